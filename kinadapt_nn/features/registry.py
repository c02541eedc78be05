"""The contract every features type fulfils, and what its builder is given.

A features type is one module (``features/adjoint.py``, ``rbf.py``, ``neural.py``, ``oracle.py``)
that defines its ``Features`` subclass (``features/base.py``: ``J_hat = Y(q) theta`` and the
regressor ``Phi``) and

* ``build(ctx: FeaturesContext) -> Built`` -- the features object and theta0 (p,) of one run,
  from what the robot knows (``ctx.known``), the nominal workspace (``ctx.workspace``) and the two
  declared numbers of experiment design (``ctx.offset_estimate_f_m``, ``ctx.true_offset_f_m``);
* ``SPEC = FeaturesSpec(name, doc, build, ...)``.

Registering it is one line in ``features/__init__.py`` (docs/architecture.md, "Adding a features
type"). The config's ``run.features`` takes any registered name; the names, the default, the
choices of ``kinadapt compare`` and ``kinadapt config`` are read from the registry.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple, Protocol

import numpy as np

from kinadapt_nn.features.base import Features
from kinadapt_nn.known import KnownCfg


class Built(NamedTuple):
    """What a builder returns."""

    features: Features  #: J_hat = Y(q) theta of the run
    theta0: np.ndarray  #: (p,) the initial parameters


class Workspace(Protocol):
    """Where the arm works, on the known model: the nominal (CAD) tool on the nominal arm at the
    known bores. Set-up planning for features that place something in joint space (the RBF's
    centres); the runs supply it (``runs.build``, from ``sim.workspace``), so no features module
    reaches the simulator."""

    n_bores: int  #: known bores of the cell (1 without a work cell)

    def paths(self, n: int) -> list[np.ndarray]:
        """Per known bore, ``n`` configurations with the nominal tip on the bore axis from 10 mm
        above the entrance to 50 mm deep. -> [(n, 7)] [rad], in the cell's bore order."""

    def sample(self, path: np.ndarray, n: int, sigma_rad: float, rng: np.random.Generator) -> np.ndarray:
        """``n`` configurations: random points on ``path`` plus N(0, sigma) joint noise. -> (n, 7)."""


@dataclass(frozen=True)
class FeaturesContext:
    """What a builder may use. Everything but the last two fields is known to a real cell."""

    known: KnownCfg  #: sensing (S, W, nominal offset), adaptation (Omega, priors), features settings, arm
    workspace: Workspace  #: the nominal insertion paths (set-up planning on the known model)
    #: (3,) [m] in f: the initial offset estimate (experiment design: the true offset +
    #: ``adaptation.initial_error_m``; a real cell's CAD value). A builder that uses it sets
    #: ``FeaturesSpec.theta0_per_episode``
    offset_estimate_f_m: np.ndarray
    #: (3,) [m] in f: the TRUE offset -- truth, for a declared baseline only (the oracle)
    true_offset_f_m: np.ndarray


@dataclass(frozen=True)
class FeaturesSpec:
    """One features type: its name, its builder and what the run side asks of it."""

    name: str  #: the config's ``run.features`` value
    doc: str  #: one line for help texts and docs tables
    build: Callable[[FeaturesContext], Built]  #: the features and theta0 of one run
    #: theta0 depends on the episode's tool (it uses ``offset_estimate_f_m`` or ``true_offset_f_m``):
    #: a batch builds it per episode; otherwise one build serves every episode of a batch
    theta0_per_episode: bool = False
    #: built on the truth (the oracle): a reference, not one of the types ``kinadapt compare`` and
    #: ``kinadapt reproduce`` run by default
    baseline: bool = False
    #: relative cost of one insertion (the adjoint's = 1; measured per step), for the order
    #: ``kinadapt compare`` starts its jobs in
    cost: float = 1.0


def registry(*specs: FeaturesSpec) -> dict[str, FeaturesSpec]:
    """name -> FeaturesSpec, refusing duplicate names."""
    out: dict[str, FeaturesSpec] = {}
    for s in specs:
        if s.name in out:
            raise ValueError(f"two features types named {s.name!r}")
        out[s.name] = s
    return out
