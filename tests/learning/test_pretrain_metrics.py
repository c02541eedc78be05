"""``kinadapt pretrain``'s metrics.json: its history says what each column is."""

from __future__ import annotations

import json

from kinadapt_nn.learning.pretrain import load_pretrain_config, pretrain

TINY = ["data.n_train=12", "data.n_heldout=4", "data.n_support=8", "data.n_query=4", "train.steps=6",
        "train.batch_instances=4", "train.eval_every=3", "train.checkpoint_every=3", "net.hidden=16",
        "net.n_features=4"]


def test_metrics_history_is_named_columns(tmp_path):
    pretrain(load_pretrain_config(None, TINY), tmp_path, progress=False)
    hist = json.loads((tmp_path / "metrics.json").read_text())["history"]
    assert list(hist) == ["step", "train_rel_jacobian_error_rms", "heldout_rel_jacobian_error_median"]
    assert hist["step"] == [3, 6]  # one entry per evaluation (train.eval_every = 3)
    assert all(len(v) == 2 and all(x > 0 for x in v) for v in hist.values())
