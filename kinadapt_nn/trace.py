"""The run-log format (``trace.npz``), versioned and self-describing.

A trace is one NumPy ``.npz`` archive. Every array's first axis is the logged sample
(``t_s`` gives its time). The archive's ``meta`` entry is a JSON string with
``format = "kinadapt-trace"``, ``version``, ``dt_s`` (sample time of the log), the
channel table (name -> unit, frame, description) and run constants. Channels whose name
starts with ``truth_`` are ground truth, logged for evaluation only; no controller-side
channel is computed from them.

Channel table (``CHANNELS`` below is the single source; the README lists it):
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from kinadapt_nn.errors import KinadaptError

TRACE_FORMAT = "kinadapt-trace"
TRACE_VERSION = 1

#: name -> (per-sample shape, unit, frame, description)
CHANNELS: dict[str, tuple[tuple[int, ...], str, str, str]] = {
    "t_s": ((), "s", "-", "time since the start of the episode"),
    "q_rad": ((7,), "rad", "joint", "joint encoder positions"),
    "qdot_rad_s": ((7,), "rad/s", "joint", "joint velocities"),
    "q_ref_rad": ((7,), "rad", "joint", "joint servo position reference"),
    "wrench_raw_f": ((6,), "N, N m", "f (about O)", "raw F/T reading: flange on tool [f; m]"),
    "w_env_w": ((6,), "N, N m", "w (about O)", "tared wrench tool -> environment [f; m]"),
    "s": ((6,), "m, N, N m", "bore", "sensor vector [d, F_lat_x, F_lat_y, M_x, M_y, M_z]"),
    "s_dot_meas": ((6,), "per s", "bore", "filtered measured sensor rate"),
    "s_dot_pred": ((6,), "per s", "bore", "filtered predicted rate J_hat qdot"),
    "F_value": ((6,), "N, m, m, rad, rad, rad", "bore", "value force -grad_s V"),
    "xi": ((6,), "m/s, rad/s", "w (at O)", "admittance twist state [v_O; omega]"),
    "V": ((), "J", "-", "value function V(s)"),
    "lambda_min": ((), "-", "-", "lambda_min(W J_hat J_hat^T W)"),
    "theta": ((-1,), "feature units", "-", "parameter estimate (adjoint: offset O->tip in f, m)"),
    "drive_scale": ((), "-", "-", "drive ramp rho in [0, 1] (0 while taring)"),
    "eps_w": ((6,), "-", "bore", "W-scaled filtered prediction error W (s_dot_meas - s_dot_pred)"),
    "adapt_gate": ((), "-", "-", "1 when adapting (sensed contact), 0 in free space"),
    "theta_dot_track": ((-1,), "per s", "-", "tracking term of the law, -Gamma Phi^T F"),
    "theta_dot_pred": ((-1,), "per s", "-", "prediction term of the law / dt"),
    "depth_ok": ((), "bool", "-", "success channel: d >= d_seat - tol"),
    "force_ok": ((), "bool", "-", "success channel: |F_lat| < limit"),
    "moment_ok": ((), "bool", "-", "success channel: |M| < limit"),
    "truth_tip_depth_m": ((), "m", "bore", "TRUTH: true tip depth below the entrance"),
    "truth_tip_pos_w_m": ((3,), "m", "w", "TRUTH: true tip position"),
    "truth_contact_face": ((), "bool", "-", "TRUTH: peg touches the block top face"),
    "truth_contact_bore": ((), "bool", "-", "TRUTH: peg touches bore walls/edge/floor"),
    "truth_contact_force_N": ((), "N", "-", "TRUTH: total normal contact force"),
    "phi_norm2": ((), "1/s^2", "-", "||W Phi_f||_2^2 of the prediction step (0 when not adapting)"),
    "theta_uncertainty": ((), "-", "-", "sqrt(tr P / tr P0): theta's remaining uncertainty as a fraction of the prior "
                          "(kalman law; NaN for the other laws)"),
    "truth_bias_w": ((6,), "-", "bore", "TRUTH: W-scaled bias b = eps_w - W Phi_f (theta_true - theta)"),
    "truth_jacobian_rel_error": ((), "-", "-", "TRUTH: |W (J_hat - J_true)| / |W J_true| (40 Hz, held)"),
    "truth_V_tot": ((), "-", "-", "TRUTH: V_tot = gamma_d (V + kinetic + contact) + |theta~|^2/(2 Gamma)"),
}


@dataclass
class Trace:
    """Arrays of a run, keyed by channel name, plus ``meta`` (JSON-serialisable)."""

    arrays: dict[str, np.ndarray]
    meta: dict[str, Any] = field(default_factory=dict)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.arrays[name]

    def __len__(self) -> int:
        return int(self.arrays["t_s"].shape[0])

    def save(self, path: Path) -> None:
        """Write atomically (temp file + rename): a crash never leaves half a trace."""
        path = Path(path)
        meta = dict(self.meta)
        meta.update(
            format=TRACE_FORMAT,
            version=TRACE_VERSION,
            channels={k: {"unit": v[1], "frame": v[2], "description": v[3]} for k, v in CHANNELS.items()},
        )
        from kinadapt_nn.runio import atomic_write

        def write(tmp: str) -> None:  # np.savez_compressed's layout (one .npy per array in a zip) at
            # zlib level 1: a third of level 6's time on these float channels, the file ~5 % larger
            import zipfile

            with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1) as zf:
                for name, arr in (("meta", np.array(json.dumps(meta))), *self.arrays.items()):
                    with zf.open(f"{name}.npy", "w", force_zip64=True) as fh:
                        np.lib.format.write_array(fh, np.asanyarray(arr), allow_pickle=False)

        atomic_write(path, write)

    @classmethod
    def load(cls, path: Path) -> Trace:
        """Read and validate a trace; one-line ``KinadaptError`` if it is not one."""
        path = Path(path)
        if not path.is_file():
            raise KinadaptError(f"trace file '{path}' not found")
        try:
            with np.load(path, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError, RuntimeError) as exc:
            first = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:120]
            if "pickle" in first.lower() or "object arrays" in first.lower():  # never load pickled objects
                first = "it is not NumPy arrays; pickled Python objects are never loaded"
            raise KinadaptError(f"trace file '{path}' is not a readable .npz archive ({first})") from None
        if "meta" not in arrays:
            raise KinadaptError(f"trace file '{path}' has no 'meta' entry (not a kinadapt trace)")
        try:
            meta = json.loads(str(arrays.pop("meta")))
            if not isinstance(meta, dict):
                raise ValueError("meta is not a JSON object")
        except ValueError:
            raise KinadaptError(f"trace file '{path}': its 'meta' entry is not valid JSON (not a kinadapt trace)") from None
        if meta.get("format") != TRACE_FORMAT:
            raise KinadaptError(f"trace file '{path}': format {meta.get('format')!r}, expected {TRACE_FORMAT!r}")
        try:
            version = int(meta.get("version", -1))
        except (TypeError, ValueError):
            version = TRACE_VERSION + 1
        if version > TRACE_VERSION:
            raise KinadaptError(
                f"trace file '{path}' has version {meta.get('version')}; this kinadapt reads <= {TRACE_VERSION}"
            )
        for name in ("t_s", "q_rad", "qdot_rad_s", "wrench_raw_f"):
            if name not in arrays:
                raise KinadaptError(f"trace file '{path}' lacks the required channel '{name}'")
        _check_time_and_shapes(path, arrays)
        return cls(arrays=arrays, meta=meta)


def _check_time_and_shapes(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """What every reader of a trace relies on: ``t_s`` (N,) finite and strictly increasing, and the
    raw channels (N, width) numbers. (The diagnosis adds the log readers' rules: finite raw channels,
    no gaps, enough samples; ``kinadapt_nn.diagnostics.importers.load_log``.)"""
    t = arrays["t_s"]
    if t.ndim != 1 or t.dtype.kind not in "iuf":
        raise KinadaptError(f"trace file '{path}': 't_s' has shape {t.shape} ({t.dtype}); expected (N,) numbers")
    for name, width in (("q_rad", 7), ("qdot_rad_s", 7), ("wrench_raw_f", 6)):
        a = arrays[name]
        if a.shape != (t.shape[0], width) or a.dtype.kind not in "iuf":
            raise KinadaptError(f"trace file '{path}': channel '{name}' has shape {a.shape} ({a.dtype}) with 't_s' "
                                f"{t.shape}; expected (N, {width}) numbers (a damaged trace?)")
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise KinadaptError(f"trace file '{path}', sample {int(bad[0])}: 't_s' is {t[bad[0]]} (not finite)")
    back = np.flatnonzero(np.diff(t) <= 0)
    if back.size:
        k = int(back[0]) + 1
        raise KinadaptError(f"trace file '{path}', sample {k}: the time 't_s' does not increase "
                            f"({t[k]:.6g} s after {t[k - 1]:.6g} s)")


class TraceRecorder:
    """Preallocated per-step logging (the hot path only copies into arrays)."""

    def __init__(self, n_samples: int, n_params: int) -> None:
        self.n = 0
        self.cap = n_samples
        self.arrays: dict[str, np.ndarray] = {}
        for name, (shape, unit, _, _) in CHANNELS.items():
            shp = tuple(n_params if s == -1 else s for s in shape)
            dtype = bool if unit == "bool" else np.float64
            self.arrays[name] = np.zeros((n_samples, *shp), dtype=dtype)

    def record(self, **values: Any) -> None:
        i = self.n
        if i >= self.cap:
            return
        a = self.arrays
        for k, v in values.items():
            a[k][i] = v
        self.n = i + 1

    def finish(self, meta: dict[str, Any]) -> Trace:
        return Trace(arrays={k: v[: self.n].copy() for k, v in self.arrays.items()}, meta=meta)
