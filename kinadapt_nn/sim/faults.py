"""Sensor faults and disturbances between the simulator and the controller (truth side).

Applied to each ``SensorSample`` in this order: encoder quantisation, F/T bias (from
``bias_onset_s`` after the tare), Gaussian F/T noise, saturation, dropouts (the whole
sample becomes NaN), latency (the controller receives the sample of ``latency_steps`` earlier).
Seeded from ``run.seed`` so a run is reproducible.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from kinadapt_nn.config import FaultsCfg
from kinadapt_nn.sim.adapter import SensorSample


class SensorFaults:
    def __init__(self, cfg: FaultsCfg, seed: int, bias_onset_s: float) -> None:
        self.cfg = cfg
        self.rng = np.random.default_rng(np.random.SeedSequence([seed, 0xFA017]))
        self.onset = bias_onset_s + cfg.bias_onset_s  # after the tare window ends
        self.bias = np.concatenate([np.asarray(cfg.ft_bias_N, dtype=float), np.zeros(3)])
        self.noise = np.array([cfg.ft_noise_N] * 3 + [cfg.ft_noise_Nm] * 3)
        self.queue: deque = deque()
        self.dropped = 0

    @staticmethod
    def active(cfg: FaultsCfg) -> bool:
        return bool(
            cfg.ft_noise_N or cfg.ft_noise_Nm or any(cfg.ft_bias_N) or cfg.ft_dropout_prob or cfg.ft_saturation_N
            or cfg.encoder_resolution_rad or cfg.latency_steps
        )

    def __call__(self, t: float, s: SensorSample) -> SensorSample:
        c = self.cfg
        q, qd, w = s.q_rad.copy(), s.qdot_rad_s.copy(), s.wrench_raw_f.copy()
        if c.encoder_resolution_rad:
            q = np.round(q / c.encoder_resolution_rad) * c.encoder_resolution_rad
        if t >= self.onset:
            w += self.bias
        if c.ft_noise_N or c.ft_noise_Nm:
            w += self.noise * self.rng.standard_normal(6)
        if c.ft_saturation_N:
            w[:3] = np.clip(w[:3], -c.ft_saturation_N, c.ft_saturation_N)
        if c.ft_dropout_prob and self.rng.random() < c.ft_dropout_prob:
            w[:] = np.nan
            self.dropped += 1
        out = SensorSample(q, qd, w)
        if c.latency_steps:
            self.queue.append(out)
            if len(self.queue) <= c.latency_steps:
                return self.queue[0]
            return self.queue.popleft()
        return out
