"""The two accounts of free space and contact in a user's log (``ContactAccounts``): the data's
(``userlog.detect_contact``) and the declared contact geometry's (``contact_model.declared_contact``),
and the mask helpers they share (``_widen``, ``_windows``)."""

from __future__ import annotations

import dataclasses

import numpy as np

from kinadapt_nn.diagnostics.setup import SetupCfg


def _widen(mask: np.ndarray, k: int) -> np.ndarray:
    """(n,) bool ``mask`` widened by ``k`` samples on each side (unchanged for k <= 0)."""
    if k <= 0 or not mask.any():
        return mask
    return np.convolve(mask.astype(float), np.ones(2 * k + 1), "same") > 0


def _windows(mask: np.ndarray, t: np.ndarray) -> list[list[float]]:
    edges = np.flatnonzero(np.diff(np.r_[0, mask.astype(int), 0]))
    return [[float(t[a] - t[0]), float(t[min(b, len(t)) - 1] - t[0])] for a, b in zip(edges[::2], edges[1::2])]


@dataclasses.dataclass(frozen=True)
class ContactAccounts:
    """One account of free space and contact: the data's (the force beyond the calibrated tool,
    ``detect_contact``) and the declared geometry's (``contact_model.declared_contact``); the rows
    used as contact are those either calls contact, so that no row is fitted as free space while
    one account says it touches."""

    used: np.ndarray  #: (n,) bool contact as used
    report: dict  #: the report's ``contact.accounts``
    data: np.ndarray  #: (n,) bool the data's account
    disputed: np.ndarray | None = None  #: (n,) bool where the two disagree (beyond the data's margin)

    @staticmethod
    def of(data: np.ndarray, declared: np.ndarray | None, t: np.ndarray, setup: SetupCfg) -> "ContactAccounts":
        if declared is None:
            return ContactAccounts(data, {"data_windows_s": _windows(data, t), "declared": None,
                                          "used": "the data's (no contact geometry declared)"}, data)
        used = data | declared
        wide = declared  # the data's windows are widened by margin_s (``detect_contact``): compared beyond it
        if len(t) > 1 and not setup.log.static:
            wide = _widen(declared, int(round(setup.contact.margin_s / float(np.median(np.diff(t))))))
        only_geom, only_data = declared & ~data, data & ~wide
        why = []
        if only_geom.mean() >= 0.005:
            why.append(f"{only_geom.mean():.0%} of the log is contact by the declared geometry but under the data's "
                       f"detection threshold ({setup.contact.detect_force_N:g} N): taken as contact (light contacts "
                       "there are not free space)")
        if only_data.mean() >= 0.005:
            why.append(f"{only_data.mean():.0%} shows a force beyond the tool model where the declared geometry cannot "
                       "touch: taken as contact (something touched outside the declared geometry)")
        disputed = only_geom | only_data
        if why and setup.contact.mode == "tip" and setup.contact.declared_geometry:
            why.append("where the declared geometry's wrench predicts more than the threshold and the data show "
                       "nothing, or the data show a force where it cannot touch, the rows are left out of the fit "
                       "([analysis] exclude_s in the set-up used)")
        return ContactAccounts(used, {
            "data_windows_s": _windows(data, t), "declared_windows_s": _windows(declared, t),
            "disputed_windows_s": _windows(disputed, t),
            "used": "contact where either account says so" + ("; " + "; ".join(why) if why else
                                                              " (the two agree)")}, data, disputed)
