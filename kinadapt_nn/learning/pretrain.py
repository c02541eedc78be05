"""Offline pretraining of the Jacobian basis across randomised tools and arms.

Data set (deterministic from ``seed``): instances = (tool, arm) pairs. Tools: lateral offset
uniform in a disc, length uniform, grasp tilt uniform (recorded; a rigid tool's tilt does not
change its Jacobian, eq. ft_factor). Arms: with probability ``arm_error_fraction`` small
kinematic errors (link lengths, joint zero offsets: ``kinadapt_nn.sim.truth``), else
nominal. Configurations: around the insertion workspace (``kinadapt_nn.sim.workspace``). Targets:
the true sensor Jacobian rows 1..5 (``kinadapt_nn.sim.truth``) minus the nominal model, W-scaled.
Held-out instances are drawn from the same distribution and never trained on.

Training: closed-form per-instance least-squares heads on a support set, loss on a query set
(the body learns a basis in which any tool/arm is a linear combination). Writes, into ``--out``:
``model.safetensors`` (the checkpoint, atomically, with metadata and a content hash:
``kinadapt_nn.learning.weights``), ``metrics.json``, ``tb/`` (TensorBoard: train loss, held-out
Jacobian error), and ``train_state.pt`` while training (resume after an interruption gives the
same result; torch's format, as it holds the optimiser's state). The resume state holds only
tensors, plain dicts, lists, strings and numbers and is read with ``torch.load(...,
weights_only=True)``: nothing in it is unpickled as code, so a planted file cannot run any.
"""

from __future__ import annotations


import json
import math
import time
from pathlib import Path
from typing import Literal, NamedTuple

import numpy as np
import torch
from pydantic import BaseModel, ConfigDict, Field

import kinadapt_nn
from kinadapt_nn.config import ExperimentCfg, load_toml_model
from kinadapt_nn.errors import ConfigError, KinadaptError
from kinadapt_nn.learning.checkpoint import atomic_torch_save, save_checkpoint
from kinadapt_nn.learning.nets import N_JOINTS, N_ROWS, JacobianBasisNet, least_squares_heads
from kinadapt_nn.robot import PANDA_MJCF
from kinadapt_nn.sensing import channel_metric, nominal_sensor_map
from kinadapt_nn.known import BORE_AXIS_W
from kinadapt_nn.learning.torch_kinematics import build_chain_from_model, flange_kinematics_pk, nominal_panda_chain
from kinadapt_nn.sim.truth import (TrueSensorJacobian, perturbed_arm_model, random_arm_errors, sensor_jacobian_rows,
                                   sensor_jacobian_rows_batch)
from kinadapt_nn.sim.workspace import insertion_path, sample_cell

TRAIN_STATE_FORMAT = "kinadapt-train-state"
TRAIN_STATE_VERSION = 2  # 2: weights_only-loadable (no pickled objects)


class _P(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class ToolDistCfg(_P):
    lateral_radius_m: float = Field(0.006, ge=0.0)  # [m] lateral offset uniform in this disc
    length_min_m: float = Field(0.08, gt=0.0)  # [m] tool length (axial offset) range
    length_max_m: float = Field(0.13, gt=0.0)
    tilt_max_deg: float = Field(3.0, ge=0.0)  # [deg] grasp tilt (recorded; no effect on J)


class ArmDistCfg(_P):
    arm_error_fraction: float = Field(0.5, ge=0.0, le=1.0)  # [-] share of instances with arm errors
    link_sigma_m: float = Field(0.001, ge=0.0)  # [m] link length error std
    joint_sigma_rad: float = Field(0.004, ge=0.0)  # [rad] joint zero offset std


class DataCfg(_P):
    n_train: int = Field(768, ge=8)  # instances (tool, arm) for training
    n_heldout: int = Field(96, ge=4)  # instances never trained on
    n_support: int = Field(32, ge=4)  # configurations per instance used to fit the head
    n_query: int = Field(16, ge=2)  # configurations per instance used for the loss
    joint_sigma_rad: float = Field(0.03, gt=0.0)  # [rad] workspace spread about the insertion path
    bores_w_m: tuple[tuple[float, float, float], ...] = ()  # [m] a work cell's bores: configurations about each one's path (() = the one default bore)


class NetCfg(_P):
    structure: Literal["basis", "per_entry"] = "basis"  # matrix-valued basis or paper's per-entry
    n_features: int = Field(12, ge=1, le=256)  # p (basis) or K (per-entry: p = 35 K)
    hidden: int = Field(64, ge=4, le=1024)  # hidden width of the two tanh layers


class TrainCfg(_P):
    steps: int = Field(1500, ge=1)  # optimiser steps
    batch_instances: int = Field(32, ge=1)  # instances per step
    lr: float = Field(3e-3, gt=0.0)  # Adam learning rate (cosine decay to 5 %)
    ridge: float = Field(1e-4, gt=0.0)  # LS head ridge (W-scaled units)
    eval_every: int = Field(100, ge=1)  # [steps] held-out evaluation + TensorBoard
    checkpoint_every: int = Field(250, ge=1)  # [steps] resumable training state
    device: Literal["auto", "cpu", "cuda"] = "auto"  # auto = CUDA when present


class PretrainCfg(_P):
    seed: int = Field(0, ge=0, le=2**32 - 2)  # seeds the data set (seed) and the batch draws (seed + 1)
    tools: ToolDistCfg = ToolDistCfg()
    arms: ArmDistCfg = ArmDistCfg()
    data: DataCfg = DataCfg()
    net: NetCfg = NetCfg()
    train: TrainCfg = TrainCfg()


def load_pretrain_config(path: Path | None, overrides=()) -> PretrainCfg:
    cfg = load_toml_model(PretrainCfg, path, overrides, "pretrain/default.toml")
    if cfg.tools.length_max_m < cfg.tools.length_min_m:
        raise ConfigError("tools.length_max_m must be >= tools.length_min_m")
    return cfg


# ----------------------------------------------------------------------------------------- data
class _Instance(NamedTuple):
    """One randomised (tool, arm) pair and its configurations (drawn from the data set's RNG)."""

    offset: np.ndarray  # (3,) [m] true tool offset in f
    tilt_deg: np.ndarray  # (2,) [deg] grasp tilt (recorded only)
    arm_error: bool  # whether the arm carries kinematic errors
    link: np.ndarray  # (8,) [m] link length errors (zeros without arm errors)
    joint: np.ndarray  # (7,) [rad] joint zero offsets (zeros without arm errors)
    q: np.ndarray  # (N, n) [rad] configurations


def _draw_instances(cfg: PretrainCfg, path, rng: np.random.Generator, n_instances: int) -> list[_Instance]:
    """The data set's random draws, in the order of the original per-instance loop. ``path``: one
    insertion path (n, 7) or a work cell's list of them (``sample_cell``)."""
    td, N = cfg.tools, cfg.data.n_support + cfg.data.n_query
    out = []
    for _ in range(n_instances):
        rad = td.lateral_radius_m * math.sqrt(rng.random())
        ang = 2 * math.pi * rng.random()
        offset = np.array([rad * math.cos(ang), rad * math.sin(ang), rng.uniform(td.length_min_m, td.length_max_m)])
        tilt = rng.uniform(-td.tilt_max_deg, td.tilt_max_deg, 2)
        has_err = rng.random() < cfg.arms.arm_error_fraction
        link, joint = random_arm_errors(rng, cfg.arms.link_sigma_m, cfg.arms.joint_sigma_rad)  # drawn either way
        if not has_err:
            link, joint = np.zeros(8), np.zeros(7)
        qs = sample_cell(path, N, cfg.data.joint_sigma_rad, rng)
        out.append(_Instance(offset, tilt, bool(has_err), link, joint, qs))
    return out


def _true_rows_mujoco(inst: _Instance, S: np.ndarray, l_nom: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Reference path: MuJoCo one configuration at a time (``TrueSensorJacobian``).
    -> true rows 1..5 (N, 5, n), nominal-model rows 1..5 (N, 5, n), not W-scaled."""
    truth = TrueSensorJacobian(S, l_nom, inst.offset, PANDA_MJCF, inst.link, inst.joint)
    rows_true = np.empty((len(inst.q), N_ROWS, N_JOINTS))
    rows_nom = np.empty((len(inst.q), N_ROWS, N_JOINTS))
    for k, q in enumerate(inst.q):
        rows_true[k] = truth(q)[1:]
        _, R_n, J_n = truth.nominal(q)
        rows_nom[k] = sensor_jacobian_rows(S[1:], R_n, J_n, l_nom)
    return rows_true, rows_nom


def _arm_kinematics_torch(chain, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Batched pytorch-kinematics flange rotation (B, 3, 3) and Jacobian (B, 6, n), as numpy."""
    with torch.no_grad():
        kin = flange_kinematics_pk(chain, torch.from_numpy(q))
    return kin.R_w_f.numpy(), kin.J.numpy()


def make_dataset(
    cfg: PretrainCfg,
    exp: ExperimentCfg | None = None,
    progress: bool = False,
    kinematics: Literal["mujoco", "torch"] = "mujoco",
) -> dict[str, np.ndarray]:
    """Instances, configurations and W-scaled residual targets. Deterministic from ``cfg.seed``.

    Returns arrays: ``q`` (I, N, 7), ``r`` (I, N, 5, 7) residual W (J_true - J_nom) rows 1..5,
    ``jn`` (I,) W-scaled Frobenius norm of J_true rows 1..5 over the instance, ``offset`` (I, 3),
    ``tilt_deg`` (I, 2), ``link`` (I, 8), ``joint`` (I, 7), ``arm_error`` (I,) bool, and
    ``q_mean``/``q_std`` (7,) for the input normalisation. ``progress``: a bar on stderr.

    ``kinematics``: ``"mujoco"`` (default) is ``TrueSensorJacobian`` one configuration at a
    time; ``"torch"`` evaluates each arm's flange pose and Jacobian for all its configurations
    in one batched pytorch-kinematics call (the nominal arm once for all I N configurations, on
    a cached chain; each perturbed arm on a chain built from its ``perturbed_arm_model``). Both
    give the same arrays (``r`` to ~1e-13 relative, the rest bit-identical; tests). MuJoCo stays
    the default because it is faster on CPU (benchmarks/bench_pretrain_data.py, 2 cores, one run
    each: 4.6 s vs 7.7 s for the default config with 1 torch thread, 3.1 s vs 21 s with 2):
    building one pk chain costs ~16 ms against ~1.4 ms to compile the MjModel, and pk's batched
    FK + Jacobian ~17 us per configuration against ~6 us for ``mj_kinematics`` +
    ``mj_jacSite`` in a Python loop.
    """
    if kinematics not in ("torch", "mujoco"):
        raise ConfigError(f"kinematics must be 'torch' or 'mujoco', got {kinematics!r}")
    exp = exp or ExperimentCfg()
    rng = np.random.default_rng(cfg.seed)
    S = nominal_sensor_map(exp.sensing, BORE_AXIS_W)
    W = channel_metric(exp.sensing)[1:, None]  # (5, 1)
    l_nom = np.asarray(exp.sensing.nominal_offset_f_m, dtype=float)
    I = cfg.data.n_train + cfg.data.n_heldout
    N = cfg.data.n_support + cfg.data.n_query
    if cfg.data.bores_w_m:  # a work cell: every instance's configurations spread over all its bores
        from kinadapt_nn.sim.workspace import cell_paths

        exp = exp.model_copy(update={"cell": exp.cell.model_copy(update={"bores_w_m": tuple(cfg.data.bores_w_m)})})
        insts = _draw_instances(cfg, cell_paths(exp), rng, I)
    else:
        insts = _draw_instances(cfg, insertion_path(exp), rng, I)
    q = np.stack([inst.q for inst in insts])  # (I, N, n)
    from tqdm import tqdm

    bar = tqdm(insts, desc="pretrain data", unit="instance", disable=not progress, leave=False)
    if kinematics == "mujoco":
        rows = [_true_rows_mujoco(inst, S, l_nom) for inst in bar]
        rows_true = np.stack([rt for rt, _ in rows])  # (I, N, 5, n)
        rows_nom = np.stack([rn for _, rn in rows])  # (I, N, 5, n)
    else:
        R_n, J_n = _arm_kinematics_torch(nominal_panda_chain(torch.float64, "cpu"), q.reshape(I * N, N_JOINTS))
        R_n, J_n = R_n.reshape(I, N, 3, 3), J_n.reshape(I, N, 6, N_JOINTS)
        rows_nom = np.stack([sensor_jacobian_rows_batch(S[1:], R_n[i], J_n[i], l_nom) for i in range(I)])
        rows_true = np.empty_like(rows_nom)
        for i, inst in enumerate(bar):
            R_t, J_t = R_n[i], J_n[i]
            if inst.link.any() or inst.joint.any():  # as TrueSensorJacobian: the true arm differs
                arm = perturbed_arm_model(PANDA_MJCF, inst.link, inst.joint)
                R_t, J_t = _arm_kinematics_torch(build_chain_from_model(arm, torch.float64, "cpu"), inst.q)
            rows_true[i] = sensor_jacobian_rows_batch(S[1:], R_t, J_t, inst.offset)
    bar.close()
    r = W * (rows_true - rows_nom)  # (I, N, 5, n)
    jt = W * rows_true  # (I, N, 5, n)
    data = {
        "q": q,
        "r": r,
        "jn": np.sqrt(np.mean(np.sum(jt**2, axis=(2, 3)), axis=1)),
        "offset": np.stack([inst.offset for inst in insts]),
        "tilt_deg": np.stack([inst.tilt_deg for inst in insts]),
        "link": np.stack([inst.link for inst in insts]),
        "joint": np.stack([inst.joint for inst in insts]),
        "arm_error": np.array([inst.arm_error for inst in insts]),
    }
    allq = data["q"][: cfg.data.n_train].reshape(-1, N_JOINTS)
    data["q_mean"] = allq.mean(axis=0)
    data["q_std"] = allq.std(axis=0) + 1e-6
    return data


def calibrated_arm_moment(theta: np.ndarray, arm_error: np.ndarray) -> dict:
    """The second moment about 0 of the heads ``theta`` (I, p) of the instances on the nominal arm
    (``arm_error`` (I,) False): the neural prior for an arm whose kinematics are calibrated
    (``features.neural_prior = "calibrated_arm"``). A rigid tool's sensor Jacobian is linear in
    its offset (eq. ft_factor), so these heads span a 3-dimensional subspace. -> meta entries."""
    T = np.asarray(theta, dtype=float)[~np.asarray(arm_error, dtype=bool)]
    if len(T) == 0:
        return {}
    M = T.T @ T / len(T)
    return {"theta_moment_calibrated_arm": [[float(x) for x in row] for row in M],
            "theta_moment_calibrated_arm_heads": int(len(T))}


def _bad_state(path: Path, why: str) -> KinadaptError:
    return KinadaptError(f"resume state '{path}' {why}; pass --overwrite to start afresh (or choose another --out)")


def load_train_state(path: Path, cfg_json: dict) -> dict:
    """Read a resume state written by ``pretrain`` for the config ``cfg_json``: tensors, plain
    dicts, lists, strings and numbers only (``weights_only=True``: no pickled code is ever run;
    the numpy RNG state is a plain dict of ints). One-line ``KinadaptError`` for anything wrong."""
    try:
        st = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for empty, corrupt or planted files
        raise _bad_state(path, f"is corrupt or not a kinadapt training state ({type(exc).__name__})") from None
    if not isinstance(st, dict) or st.get("format") != TRAIN_STATE_FORMAT:
        raise _bad_state(path, "is not a kinadapt training state")
    if st.get("version") != TRAIN_STATE_VERSION or not {"net", "opt", "rng", "step", "config"} <= set(st):
        raise _bad_state(path, f"has version {st.get('version')!r}; this kinadapt resumes version "
                               f"{TRAIN_STATE_VERSION}")
    if st["config"] != cfg_json:
        raise ConfigError(f"'{path}' was written by a different pretrain config; use another --out "
                          "or pass --overwrite to start afresh")
    return st


# -------------------------------------------------------------------------------------- training
def _device(cfg: PretrainCfg) -> torch.device:
    if cfg.train.device == "cuda" or (cfg.train.device == "auto" and torch.cuda.is_available()):
        return torch.device("cuda")
    return torch.device("cpu")


def _relative_error(net, q_s, r_s, q_q, r_q, jn, ridge) -> torch.Tensor:
    """Per-instance relative Jacobian error on the query set with heads fit on the support set."""
    theta = least_squares_heads(net, q_s, r_s, ridge)
    pred = net.residual(q_q, theta[:, None, :].expand(-1, q_q.shape[1], -1))
    err = torch.sqrt(torch.mean(torch.sum((pred - r_q) ** 2, dim=(-2, -1)), dim=1))
    return err / jn


def adjoint_best_fit_error(data: dict, n_train: int, n_support: int) -> np.ndarray:
    """Reference: the 3-parameter adjoint's best LS fit (residual is affine in the offset, so a
    linear LS on support with basis d J / d offset is exact) evaluated on the query set.
    Returns the per-instance relative error of the held-out instances."""
    # In W-scaled residual space the adjoint spans {d(S Ad(R l) J_arm)/dl}: computed numerically.
    exp = ExperimentCfg()
    S = nominal_sensor_map(exp.sensing, BORE_AXIS_W)
    W = channel_metric(exp.sensing)[1:, None]
    l_nom = np.asarray(exp.sensing.nominal_offset_f_m, dtype=float)
    nominal = TrueSensorJacobian(S, l_nom, l_nom, PANDA_MJCF)

    errs = []
    for i in range(n_train, len(data["q"])):
        qs = data["q"][i]
        basis = []
        for q in qs:
            _, R, J = nominal.nominal(q)
            cols = [W * (sensor_jacobian_rows(S[1:], R, J, e) - sensor_jacobian_rows(S[1:], R, J, 0 * e)) for e in np.eye(3)]
            basis.append(np.stack(cols, axis=-1))  # (5, 7, 3)
        B = np.array(basis)  # (N, 5, 7, 3); residual = B (l - l_nom)
        A = B[:n_support].reshape(-1, 3)
        x, *_ = np.linalg.lstsq(A, data["r"][i][:n_support].reshape(-1), rcond=None)
        pred = B[n_support:] @ x
        e = np.sqrt(np.mean(np.sum((pred - data["r"][i][n_support:]) ** 2, axis=(1, 2))))
        errs.append(e / data["jn"][i])
    return np.array(errs)


class _Training:
    """The training's state: the data set (as float64 tensors on the device), the network, the
    optimiser, the instance sampler and the step; resumed from ``train_state.pt`` if there is one."""

    def __init__(self, cfg: PretrainCfg, out: Path, progress: bool) -> None:
        self.cfg, self.dev = cfg, _device(cfg)
        self.cfg_json = cfg.model_dump(mode="json")
        self.state_path = out / "train_state.pt"
        # the resume state is checked before the slow data set
        resume = load_train_state(self.state_path, self.cfg_json) if self.state_path.is_file() else None
        self.data = data = make_dataset(cfg, progress=progress)
        f64 = torch.float64
        self.q = torch.as_tensor(data["q"], dtype=f64, device=self.dev)  # (I, N, 7)
        self.r = torch.as_tensor(data["r"], dtype=f64, device=self.dev)  # (I, N, 5, 7)
        self.jn = torch.as_tensor(data["jn"], dtype=f64, device=self.dev)  # (I,)
        torch.manual_seed(cfg.seed)
        net = JacobianBasisNet(cfg.net.structure, cfg.net.n_features, cfg.net.hidden, data["q_mean"], data["q_std"])
        self.net = net.double().to(self.dev)
        self.opt = torch.optim.Adam(self.net.parameters(), lr=cfg.train.lr)
        self.rng = np.random.default_rng(cfg.seed + 1)
        self.step = 0
        if resume is not None:
            try:
                self.net.load_state_dict(resume["net"])
                self.opt.load_state_dict(resume["opt"])
                self.rng.bit_generator.state = resume["rng"]
                self.step = int(resume["step"])
            except (KeyError, RuntimeError, TypeError, ValueError) as exc:
                raise _bad_state(self.state_path, f"does not match the network ({type(exc).__name__})") from None

    def train_step(self) -> torch.Tensor:
        """One Adam step on ``batch_instances`` training instances (cosine learning rate down to
        5 %). -> the loss, mean squared relative Jacobian error on their query sets."""
        cfg, nt, ns = self.cfg, self.cfg.data.n_train, self.cfg.data.n_support
        q, r, jn = self.q, self.r, self.jn
        idx = torch.as_tensor(self.rng.choice(nt, cfg.train.batch_instances, replace=False), device=self.dev)
        lr = cfg.train.lr * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * self.step / cfg.train.steps)))
        for g in self.opt.param_groups:
            g["lr"] = lr
        err = _relative_error(self.net, q[idx, :ns], r[idx, :ns], q[idx, ns:], r[idx, ns:], jn[idx], cfg.train.ridge)
        loss = torch.mean(err**2)
        self.opt.zero_grad()
        loss.backward()
        self.opt.step()
        self.step += 1
        return loss

    def heldout_error(self) -> np.ndarray:
        """Per held-out instance, the relative Jacobian error on its query set, heads fit on its support set."""
        nt, ns = self.cfg.data.n_train, self.cfg.data.n_support
        q, r = self.q, self.r
        with torch.no_grad():
            he = _relative_error(self.net, q[nt:, :ns], r[nt:, :ns], q[nt:, ns:], r[nt:, ns:], self.jn[nt:],
                                 self.cfg.train.ridge)
        return he.cpu().numpy()

    def save_state(self) -> None:
        atomic_torch_save(
            {"format": TRAIN_STATE_FORMAT, "version": TRAIN_STATE_VERSION, "net": self.net.state_dict(),
             "opt": self.opt.state_dict(), "rng": self.rng.bit_generator.state, "step": self.step,
             "config": self.cfg_json},
            self.state_path,
        )


def pretrain(cfg: PretrainCfg, out: Path, progress: bool = True, stop_after: int | None = None) -> dict:
    """Train (or resume) into ``out``: model.safetensors, metrics.json, tb/. ``stop_after``
    simulates an interruption (tests). -> metrics.json's content (or ``{"interrupted_at": step}``)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    run = _Training(cfg, out, progress)
    adj_err = adjoint_best_fit_error(run.data, cfg.data.n_train, cfg.data.n_support)
    hist = _train(run, out, adj_err, progress, stop_after)
    if hist is None:
        return {"interrupted_at": run.step}
    metrics = _finish(run, out, adj_err, hist)
    metrics["wall_time_s"] = time.perf_counter() - t0
    from kinadapt_nn.runio import write_text_atomic

    write_text_atomic(out / "metrics.json", json.dumps(metrics, indent=1) + "\n")
    run.state_path.unlink(missing_ok=True)
    return metrics


def _train(run: _Training, out: Path, adj_err: np.ndarray, progress: bool, stop_after: int | None) -> dict | None:
    """The training loop to ``train.steps``: TensorBoard scalars and the history every
    ``eval_every`` steps, the resume state every ``checkpoint_every``. -> metrics.json's
    "history" (one named list per column, one entry per evaluation), None when stopped at ``stop_after``."""
    from kinadapt_nn.runio import EventWriter

    cfg = run.cfg
    held_arm = run.data["arm_error"][cfg.data.n_train:]
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=cfg.train.steps, initial=run.step, desc="pretrain", unit="step")
    hist: dict[str, list] = {"step": [], "train_rel_jacobian_error_rms": [], "heldout_rel_jacobian_error_median": []}
    try:
        with EventWriter(out / "tb") as tb:
            while run.step < cfg.train.steps:
                loss = run.train_step()
                step = run.step
                if bar is not None:
                    bar.update(1)
                if step % cfg.train.eval_every == 0 or step == cfg.train.steps:
                    _evaluate(run, tb, hist, float(torch.sqrt(loss.detach())), adj_err, held_arm)
                if step % cfg.train.checkpoint_every == 0 or step == cfg.train.steps:
                    run.save_state()
                if stop_after is not None and step >= stop_after and step < cfg.train.steps:
                    return None
    finally:
        if bar is not None:
            bar.close()
    return hist


def _evaluate(run: _Training, tb, hist: dict, train_rms: float, adj_err: np.ndarray, held_arm: np.ndarray) -> None:
    """The held-out error now: TensorBoard scalars and a history entry."""
    he = run.heldout_error()
    step = run.step
    tb.add_scalar("pretrain/train_rel_jacobian_error_rms", train_rms, step)
    tb.add_scalar("pretrain/heldout_rel_jacobian_error_median", float(np.median(he)), step)
    tb.add_scalar("pretrain/heldout_rel_jacobian_error_arm_errors_median",
                  float(np.median(he[held_arm])) if held_arm.any() else 0.0, step)
    tb.add_scalar("pretrain/adjoint_heldout_rel_jacobian_error_median", float(np.median(adj_err)), step)
    hist["step"].append(step)
    hist["train_rel_jacobian_error_rms"].append(train_rms)
    hist["heldout_rel_jacobian_error_median"].append(float(np.median(he)))


def _finish(run: _Training, out: Path, adj_err: np.ndarray, hist: dict) -> dict:
    """The heads of every training instance (their mean: the online initial estimate; their
    covariance: the kalman law's neural prior), the model written. -> the metrics (no wall time)."""
    cfg, nt = run.cfg, run.cfg.data.n_train
    with torch.no_grad():
        theta_all = least_squares_heads(run.net, run.q[:nt], run.r[:nt], cfg.train.ridge).cpu().numpy()
    he = run.heldout_error()
    net, data = run.net, run.data
    n_body = sum(p.numel() for p in net.parameters())
    meta = {
        "theta0_online": "zeros: the head of the nominal (CAD) tool on the nominal arm",
        # the heads' covariance: the neural prior of the kalman law (kinadapt_nn.learning.prior)
        "theta_cov": [[float(x) for x in row] for row in np.atleast_2d(np.cov(theta_all, rowvar=False))],
        "theta_cov_heads": int(len(theta_all)),
        # the heads of the tools on the nominal arm only: the prior of a calibrated arm
        **calibrated_arm_moment(theta_all, data["arm_error"][:nt]),
        "structure": cfg.net.structure,
        "n_features": cfg.net.n_features,
        "hidden": cfg.net.hidden,
        "n_params_online": int(net.n_params),
        "n_params_body": int(n_body),
        "q_mean": [float(x) for x in data["q_mean"]],
        "q_std": [float(x) for x in data["q_std"]],
        "w_rows": [float(x) for x in channel_metric(ExperimentCfg().sensing)[1:]],
        "tool_distribution": cfg.tools.model_dump(mode="json"),
        "arm_distribution": cfg.arms.model_dump(mode="json"),
        "config": run.cfg_json,
        "library_version": kinadapt_nn.__version__,
        "torch_version": str(torch.__version__),
        "heldout_rel_jacobian_error_median": float(np.median(he)),
    }
    save_checkpoint(out / "model.safetensors", net.to("cpu"), theta_all.mean(axis=0), meta, theta_all.std(axis=0))
    held_arm = data["arm_error"][nt:]

    def median(x: np.ndarray, sel: np.ndarray) -> float | None:
        return float(np.median(x[sel])) if sel.any() else None

    return {
        "steps": run.step,
        "wall_time_s": None,
        "device": str(run.dev),
        "n_params_online": int(net.n_params),
        "n_params_body": int(n_body),
        "heldout_rel_jacobian_error_median": float(np.median(he)),
        "heldout_rel_jacobian_error_median_nominal_arm": median(he, ~held_arm),
        "heldout_rel_jacobian_error_median_arm_errors": median(he, held_arm),
        "adjoint_best_fit_rel_error_median_nominal_arm": median(adj_err, ~held_arm),
        "adjoint_best_fit_rel_error_median_arm_errors": median(adj_err, held_arm),
        "history": hist,
    }
