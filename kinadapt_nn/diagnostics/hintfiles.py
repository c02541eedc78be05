"""A hint as a ready effect file: the shape the diagnosis found, written in the public contract
(``kinadapt_nn.effects.contract``) with the fitted numbers, for the user to edit and pass back
with ``--effects``. ``effect_file(hint, ...) -> (file name, Python source)``."""

from __future__ import annotations

_HEAD = '''"""kinadapt effect file written by `kinadapt diagnose` from the hint '{shape}':
{words}.

Fitted on {source} ({explains:.0f}% of the residual the model left, held-out):
{fitted}

Edit it to the physics you suspect (the numbers above are a starting point), then pass it back:
    kinadapt diagnose LOG --setup SETUP.toml --effects {fname} [--add {func}]
An effects file is Python code that runs, like a test file (docs/missing_physics.md). The function
returns (n, 6, k): the change of s.wrench (the wrench the tool exerts on the sensor, sensor frame,
about its origin) per unit of each parameter.
"""
import numpy as np

from kinadapt_nn.diagnostics import effect
'''


def _fmt(v) -> str:
    """A fitted entry for a person: numbers to 4 significant digits, ``value ± sd unit``."""
    if isinstance(v, dict) and "value" in v:
        val, sd = v["value"], v.get("sd")
        def num(x) -> str:
            return f"{x:.4g}"

        vs = "[" + ", ".join(num(x) for x in val) + "]" if isinstance(val, list) else num(val)
        if sd is not None:
            vs += " ± " + ("[" + ", ".join(num(x) for x in sd) + "]" if isinstance(sd, list) else num(sd))
        return f"{vs} {v.get('unit', '')}".rstrip()
    return str(v)


def stem(shape: str) -> str:
    """A shape name as a file/function name part (``extra:temp_C`` -> ``extra_temp_C``)."""
    return "".join(ch if ch.isalnum() or ch == "_" else "_" for ch in shape)


def _params(names, units, cols) -> str:
    return "{" + ", ".join(f"{names[c]!r}: {units[c]!r}" for c in cols) + "}"


def _rel(rel, cols) -> str:
    return "[" + ", ".join(f"{float(rel[c]):.3g}" for c in cols) + "]"


def _deco(h: dict, cols, doc: str) -> str:
    return (f"@effect(params={_params(h['_names'], h['_units'], cols)},\n"
            f"        relevant={_rel(h['_rel'], cols)},\n        doc={doc!r})\n")


def _entries_body(func: str, h: dict, m: int, source: str, note: str) -> str:
    """A sparse per-channel shape: ENTRIES (channel, source index) of the chosen columns."""
    entries = [(c // m, c % m) for c in h["_cols"]]
    return (f"ENTRIES = {entries}  # (wrench channel 0..5 = fx fy fz tx ty tz, {note})\n\n\n"
            + _deco(h, h["_cols"], h["words"].split(":")[0] + " (hint " + h["shape"] + ")")
            + f"def {func}(s):\n    src = {source}\n    C = np.zeros((s.n, 6, len(ENTRIES)))\n"
            + "    for k, (i, j) in enumerate(ENTRIES):\n        C[:, i, k] = src[:, j]\n    return C\n")


def effect_file(h: dict, source: str) -> tuple[str, str]:
    """The effect file of hint ``h`` (an entry of ``completeness.hints`` with its private fields)."""
    shape = h["shape"]
    func = f"hint_{stem(shape)}"
    fname = f"{func}.py"
    fitted = "\n".join(f"    {k}: {_fmt(v)}" for k, v in h["fitted"].items())
    head = _HEAD.format(shape=shape, words=h["words"], source=source, explains=100 * h["explains"], fitted=fitted,
                        fname=fname, func=func)
    k = len(h["_names"])
    doc = h["words"].split(":")[0] + f" (hint {shape})"
    if shape == "sensor_constant":
        body = _deco(h, range(6), doc) + f"def {func}(s):\n    return np.broadcast_to(np.eye(6), (s.n, 6, 6)).copy()\n"
    elif shape == "world_force":
        point = h["fitted"]["point_s"]["value"]
        h3 = {**h, "_names": ["fx_w", "fy_w", "fz_w"], "_units": ["N", "N", "N"]}
        body = (f"POINT_S_M = np.array({[round(float(x), 5) for x in point]})  # [m] point of action on the tool, "
                "sensor frame (fitted)\n\n\n" + _deco(h3, range(3), "a constant world-frame force at POINT_S_M on the "
                                                       "tool (a cable, hose, spring or fixture pulling)")
                + f"def {func}(s):\n    C = np.zeros((s.n, 6, 3))\n    for axis in range(3):\n"
                "        u = s.R_ws[:, axis, :]  # the world axis in the sensor frame\n"
                "        C[:, :3, axis] = u\n        C[:, 3:, axis] = np.cross(POINT_S_M, u)\n    return C\n")
    elif shape == "time":
        order = k // 6
        body = (f"ORDER = {order}  # Legendre polynomials of the log's time, per channel\n\n\n"
                + _deco(h, range(k), doc)
                + f"def {func}(s):\n    u = 2.0 * (s.t - s.t.min()) / (s.t.max() - s.t.min()) - 1.0\n"
                "    P = np.stack([np.polynomial.legendre.Legendre.basis(d)(u) for d in range(1, ORDER + 1)], axis=1)\n"
                "    C = np.zeros((s.n, 6, 6 * ORDER))\n    for i in range(6):\n"
                "        C[:, i, i * ORDER:(i + 1) * ORDER] = P\n    return C\n")
    elif shape == "wrench_linear":
        body = _entries_body(func, h, 6, "s.wrench", "source: the measured wrench component 0..5")
    elif shape == "joint_velocity":
        dof = k // 12
        body = ("SIGN_EPS_RAD_S = 0.02  # smoothing of sign(qdot)\n"
                + _entries_body(func, h, 2 * dof, "np.hstack([s.qdot, np.tanh(s.qdot / SIGN_EPS_RAD_S)])",
                                f"source: qdot of joint 1..{dof}, then sign(qdot) of joint 1..{dof}"))
    elif shape == "joint_position":
        body = _entries_body(func, h, k // 6, "s.q - s.q.mean(axis=0)", "source: joint 1..dof position")
    elif shape == "contact_moment":
        entries = [(3 + c // 7, c % 7) for c in h["_cols"]]
        body = ("TORSION_EPS_RAD_S = 0.02  # smoothing of sign(omega) for torsional friction\n"
                f"ENTRIES = {entries}  # (moment channel 3..5 = tx ty tz, source: 0 in contact, 1..3 contact force "
                "x y z, 4..6 |f| sign(omega) x y z)\n\n\n"
                + _deco(h, h["_cols"], doc)
                + f"def {func}(s):\n    c = np.asarray(s.contact, dtype=float)[:, None]\n    f = s.contact_force_s\n"
                "    tors = np.linalg.norm(f, axis=1, keepdims=True) * np.tanh(s.omega_s / TORSION_EPS_RAD_S)\n"
                "    src = c * np.hstack([np.ones((s.n, 1)), f, tors])\n"
                "    C = np.zeros((s.n, 6, len(ENTRIES)))\n"
                "    for k, (i, j) in enumerate(ENTRIES):\n        C[:, i, k] = src[:, j]\n    return C\n")
    elif shape.startswith("extra:"):
        col = shape.split(":", 1)[1]
        body = (_deco(h, range(6), f"the wrench follows the log column {col} (hint {shape})")
                + f"def {func}(s):\n    x = s.extra[{col!r}] - np.mean(s.extra[{col!r}])\n"
                "    return x[:, None, None] * np.eye(6)[None, :, :]\n")
    else:  # pragma: no cover - every shape of the dictionary is handled above
        raise ValueError(f"no effect file for shape {shape}")
    return fname, head + "\n\n" + body


def public(h: dict) -> dict:
    """The hint without its private fields (what diagnosis.json holds)."""
    return {k: v for k, v in h.items() if not k.startswith("_")}
