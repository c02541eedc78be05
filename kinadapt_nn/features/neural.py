"""Neural features: ``Y(q)`` from a frozen pretrained body, only ``theta`` adapts online.

``J_hat(q) = K(q) + W^-1 Y(q) theta`` on rows 1..5 (``K`` the known nominal model -- the adjoint
at the nominal offset, depth row included; ``W`` the channel metric the body was trained in).
The per-step path is a hand-written numpy forward of the checkpoint's MLP (no torch, no
autograd in the loop; the weights read by ``safetensors.numpy``, ``kinadapt_nn.learning.weights``);
``tests/features/test_learned.py`` proves it equals the torch network.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from kinadapt_nn.features.adjoint import AdjointFeatures, nominal_adjoint
from kinadapt_nn.features.base import Features, KinState, Regressor
from kinadapt_nn.features.registry import Built, FeaturesContext, FeaturesSpec
from kinadapt_nn.learning.weights import N_JOINTS, N_ROWS, load_checkpoint_arrays
from kinadapt_nn.robot import MODELS_DIR
from kinadapt_nn.sensing import channel_metric


class NeuralFeatures(Features):
    """Frozen MLP body -> Y(q); ``theta`` (p,) the online output weights."""

    name = "neural"

    def __init__(self, known: AdjointFeatures, prior_offset_f: np.ndarray, checkpoint: Path, W: np.ndarray) -> None:
        sd, meta = load_checkpoint_arrays(checkpoint)  # safetensors.numpy: torch is not imported online
        self.meta = meta
        self.checkpoint = Path(checkpoint)
        self.known = known
        self.prior = np.asarray(prior_offset_f, dtype=float)
        self.structure = meta["structure"]
        self.K = int(meta["n_features"])
        self.n_params = self.K if self.structure == "basis" else N_ROWS * N_JOINTS * self.K
        self.W1, self.b1 = sd["l1.weight"], sd["l1.bias"]
        self.W2, self.b2 = sd["l2.weight"], sd["l2.bias"]
        self.W3, self.b3 = sd["l3.weight"], sd["l3.bias"]
        self.q_mean, self.q_inv_std = sd["q_mean"], 1.0 / sd["q_std"]
        w_rows = np.asarray(meta.get("w_rows", W[1:]), dtype=float)
        if not np.allclose(w_rows, W[1:]):
            from kinadapt_nn.errors import ModelFileError

            raise ModelFileError(
                f"checkpoint '{checkpoint}' was trained with channel metric {w_rows.tolist()}, this run uses "
                f"{np.asarray(W[1:]).tolist()} (retrain, or keep sensing.channel_scale as in training)"
            )
        self.inv_w = (1.0 / w_rows)[:, None, None]  # (5, 1, 1)
        if self.structure == "basis":  # fold W^-1 into the last layer: Y = (W3 h + b3) / w_row
            row_scale = np.repeat(1.0 / w_rows, N_JOINTS * self.K)  # (5 n p,), output order (i, j, k)
            self.W3, self.b3 = self.W3 * row_scale[:, None], self.b3 * row_scale
        self.theta_mean = np.asarray(meta["theta_mean"], dtype=float)
        self._cache_key: bytes | None = None
        self._cache_val: np.ndarray | None = None
        self.theta_std = np.asarray(meta.get("theta_std", np.full(self.n_params, np.inf)), dtype=float)

    @property
    def kernel(self) -> str | None:
        """"neural": the basis-structure body and regressor run in the controller's kernel (on
        the in-kernel adjoint's known part); per-entry checkpoints supply rows from Python."""
        return "neural" if self.structure == "basis" and self.known.kernel == "adjoint" else None

    def prior_cov(self, arm: str = "all_arms") -> np.ndarray:
        """theta's prior covariance about the nominal head (0). (p, p).

        ``arm = "all_arms"``: the pretraining heads' covariance (``theta_cov`` in the checkpoint,
        else their per-parameter sd) plus their mean's outer product (the heads spread about the
        nominal tool's, not about their mean). ``"calibrated_arm"``: the second moment of the heads
        of the tools on the nominal arm only (``theta_moment_calibrated_arm``; rank 3, the tool
        offset), for an arm whose kinematics are known to be right; a floor of 1e-9 of its mean
        eigenvalue keeps it invertible (the other directions then stay at the prior)."""
        if arm == "calibrated_arm":
            M = self.meta.get("theta_moment_calibrated_arm")
            if M is None:
                from kinadapt_nn.errors import ModelFileError

                raise ModelFileError(
                    f"checkpoint '{self.checkpoint}' has no calibrated-arm prior (add it with "
                    f"'python -m kinadapt_nn.learning.prior {self.checkpoint}', or set features.neural_prior = \"all_arms\")"
                )
            C = np.asarray(M, dtype=float)
            return C + 1e-9 * max(float(np.trace(C)) / len(C), 1e-30) * np.eye(len(C))
        m = self.theta_mean
        cov = self.meta.get("theta_cov")
        if cov is not None:
            C = np.asarray(cov, dtype=float)
        else:
            sd = np.where(np.isfinite(self.theta_std), self.theta_std, 0.0)
            C = np.diag(sd**2)
        C = C + np.outer(m, m)
        return C + 1e-12 * max(float(np.trace(C)) / len(C), 1e-30) * np.eye(len(C))

    def omega(self) -> tuple[np.ndarray, np.ndarray]:
        """Omega = the tool/arm family seen in training: theta_mean +- 3 std of the training heads."""
        return self.theta_mean, 3.0 * self.theta_std

    def body(self, q: np.ndarray) -> np.ndarray:
        """The MLP output in raw sensor units: Y (5, n, p) for ``basis``, psi (K,) for ``per_entry``.

        The last result is cached by the bytes of ``q`` (the controller asks twice per step:
        for J_hat and for the regressor); the returned array must not be modified."""
        key = q.tobytes()
        if key == self._cache_key:
            return self._cache_val
        self._cache_key, self._cache_val = key, self._body(q)
        return self._cache_val

    def _body(self, q: np.ndarray) -> np.ndarray:
        x = (q - self.q_mean) * self.q_inv_std
        h = np.tanh(self.W2.dot(np.tanh(self.W1.dot(x) + self.b1)) + self.b2)
        y = self.W3.dot(h) + self.b3
        if self.structure == "basis":
            return y.reshape(N_ROWS, N_JOINTS, self.K)
        return y

    def jacobian(self, kin: KinState, theta: np.ndarray) -> np.ndarray:
        J = self.known.jacobian(kin, self.prior)
        y = self.body(kin.q_rad)
        if self.structure == "basis":
            J[1:] += y @ theta
        else:
            J[1:] += (theta.reshape(N_ROWS, N_JOINTS, self.K) @ y) * self.inv_w[:, :, 0]
        return J

    def regressor(self, kin: KinState, qdot: np.ndarray) -> Regressor:
        reg0 = self.known.regressor(kin, qdot)
        known = reg0.known + reg0.Phi @ self.prior
        y = self.body(kin.q_rad)
        Phi = np.zeros((N_ROWS + 1, self.n_params))
        if self.structure == "basis":
            Phi[1:] = qdot @ y  # (n,) @ (5, n, p) -> (5, p): Y_k(q) qdot per row
        else:
            block = np.outer(qdot, y).ravel()
            w = block.size
            for i in range(N_ROWS):
                Phi[1 + i, i * w : (i + 1) * w] = block * self.inv_w[i, 0, 0]
        return Regressor(known=known, Phi=Phi)


def checkpoint_path(name: str) -> Path:
    """The checkpoint ``features.neural_checkpoint`` names: "" the shipped default; a path; or a
    shipped model by its file name ("neural_cell.safetensors"; a shipped model's name before
    safetensors, "neural_cell.pt", means its conversion: the same weights, tested)."""
    ckpt = Path(name) if name else MODELS_DIR / "neural_default.safetensors"
    if not ckpt.is_absolute() and not ckpt.exists():
        shipped = MODELS_DIR / ckpt.name
        if ckpt.suffix == ".pt":
            shipped = shipped.with_suffix(".safetensors")
        ckpt = shipped if shipped.is_file() else ckpt
    return ckpt


def build(ctx: FeaturesContext) -> Built:
    """The pretrained body on the nominal adjoint; theta0 = 0, the head of the nominal tool (zero
    residual); theta's prior: the pretraining heads' second moment about it (``features.neural_prior``)."""
    known = ctx.known
    feats = NeuralFeatures(nominal_adjoint(known), np.asarray(known.sensing.nominal_offset_f_m, dtype=float),
                           checkpoint_path(known.features.neural_checkpoint), channel_metric(known.sensing))
    feats.P0 = feats.prior_cov(known.features.neural_prior)
    return Built(feats, np.zeros(feats.n_params))


SPEC = FeaturesSpec(name="neural", doc="a pretrained network's Jacobian basis, only its output weights adapt "
                    "(features.neural_checkpoint)", build=build, cost=1.8)
