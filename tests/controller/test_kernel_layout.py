"""The kernels' constants come from one declared layout (controller/layout.py): the generated
index constants are the declaration's offsets, ``core_consts`` fills ``c`` by name (every field at
its size), and a state row's blocks are laid out as declared."""

from __future__ import annotations

import numpy as np
import pytest

from kinadapt_nn.config import load_config
from kinadapt_nn.controller import core, layout
from kinadapt_nn.controller.controller import core_consts
from kinadapt_nn.known import KnownCfg
from kinadapt_nn.runs.build import make_features
from kinadapt_nn.sensing import channel_metric


def test_the_generated_constants_are_the_declared_offsets():
    """Each c index is the sum of the sizes declared before it; counters and Layout.arr positions
    are their declaration order; core re-exports every one with the same value."""
    o = 0
    for name, size, meaning in layout.C_FIELDS:
        assert getattr(layout, name) == o and getattr(core, name) == o and meaning
        o += size
    assert layout.N_C == o == core.N_C
    for i, name in enumerate(layout.K_FIELDS):
        assert getattr(core, name) == i
    lay_names = layout.LAY_HEAD + tuple(c for _, c, _ in layout.X_BLOCKS + layout.OUT_BLOCKS)
    assert [getattr(core, name) for name in lay_names] == list(range(len(lay_names)))


def test_a_layout_row_holds_each_block_where_the_kernels_look():
    """Layout.arr[X_*] / [O_*] is the offset of the block of that name, blocks back to back with
    the declared sizes (n = 7, m = 6, p = 12, a law of 5 floats and 2 counters)."""
    lay = core.Layout(7, 6, 12, (5, 2))
    assert list(lay.arr[:5]) == [7, 6, 12, 5, 2]
    o = 0
    for name, const, size in layout.X_BLOCKS:
        assert lay.arr[getattr(core, const)] == lay.x_blocks[name][0] == o
        o += size(7, 6, 12, 5)
    assert lay.nx == o
    o = 0
    for name, const, size in layout.OUT_BLOCKS:
        assert lay.arr[getattr(core, const)] == lay.out_blocks[name][0] == o
        o += size(7, 6, 12, 5)
    assert lay.nout == o


def test_core_consts_fills_every_field_by_name():
    cfg = load_config(None, ["run.progress=false", "control.dither_rad_s=[0.05,0.04,0.03]"])
    feats, _ = make_features(cfg)
    known = KnownCfg.of(cfg)
    c = core_consts(known, feats)[0].c
    assert c.shape == (core.N_C,)
    np.testing.assert_array_equal(c[core.V_W:core.V_W + 6], channel_metric(cfg.sensing))
    np.testing.assert_array_equal(c[core.V_DITHER:core.V_DITHER + 3], [0.05, 0.04, 0.03])
    np.testing.assert_array_equal(c[core.V_LNOM:core.V_LNOM + 3], cfg.sensing.nominal_offset_f_m)
    assert c[core.DT] == cfg.run.dt_s and c[core.F_GATE] == cfg.adaptation.contact_force_N
    assert c[core.FEAT] == core.FEAT_ADJOINT and c[core.RANK_GATE_V] == core.RANK_GATE


def test_pack_c_refuses_a_missing_an_unknown_or_a_wrongly_sized_field():
    full = {name: np.arange(size, dtype=float) + 1 for name, size, _ in layout.C_FIELDS}
    c = layout.pack_c(full)
    for name, size, _ in layout.C_FIELDS:
        np.testing.assert_array_equal(c[layout.C_INDEX[name]:layout.C_INDEX[name] + size], full[name])
    with pytest.raises(ValueError, match=r"missing \['DT'\]"):
        layout.pack_c({k: v for k, v in full.items() if k != "DT"})
    with pytest.raises(ValueError, match=r"unknown field\(s\) \['DTT'\]"):
        layout.pack_c({**full, "DTT": 1.0})
    with pytest.raises(ValueError, match="V_N has 2 entries, declared 3"):
        layout.pack_c({**full, "V_N": [1.0, 2.0]})
    partial = layout.pack_c({"ALPHA": 0.5}, complete=False)
    assert partial[layout.C_INDEX["ALPHA"]] == 0.5 and np.count_nonzero(partial) == 1
