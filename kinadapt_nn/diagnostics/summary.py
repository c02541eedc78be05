"""The diagnosis's summary paragraph (``summary_text``) and its sentences, from the report's
sections (``diagnosis.json``)."""

from __future__ import annotations

import math

from kinadapt_nn.diagnostics import selection as sel
from kinadapt_nn.diagnostics import signals as sg
from kinadapt_nn.diagnostics.tip import tip_nuisance


def undecided_in_model(rep: dict) -> list[str]:
    """The effects the final model holds (selected) that the verdict leaves undecided: the model's
    fit needs them, and none is a finding (``rep``: the report's sections)."""
    return [e["effect"] for e in rep.get("ranking", []) if e.get("selected_round") is not None
            and e.get("verdict") != "present"]


def completeness_text(rep: dict) -> str:
    """The verdict on the model itself, in words (the summary's first sentence)."""
    un = rep.get("unexplained", {})
    if rep.get("model_complete", True):
        held = undecided_in_model(rep)
        if held:
            txt = (f"The model explains the log only with effects it cannot decide ({', '.join(held)}): no systematic "
                   "residual of a relevant size is left once they are fitted, and none of them is a finding.")
            hs = un.get("hints", [])
            if hs:  # sought beside them (completeness.held_undecided): a shape the library lacks fits what they leave
                txt += (" Fitted beside them, a shape outside the library still explains what they leave: it looks like "
                        + _hints_words(hs, "of what they leave held-out") + ".")
            return txt
        return "The model explains the log: no systematic residual of a relevant size is left."
    ch = un.get("channels", {})
    parts = [f"{c} ({ch[c]['structured_rms']:.3g} {ch[c]['unit']}, {ch[c]['ratio_to_noise']:.1f}x the noise floor)"
             for c in un.get("carried_by", [])]
    txt = ("Something the model does not contain is left: a structured residual in " + ", ".join(parts)
           + f" ({', '.join(un.get('phases', []))}).")
    hs = un.get("hints", [])
    if hs:
        txt += " It looks like " + _hints_words(hs, "of it held-out") + "."
    else:
        txt += " No shape of the hint dictionary explains it."
    return txt


def _hints_words(hs: list[dict], of: str) -> str:
    """The leading hints (at most three) in words: shape, its first reading, the share it explains ``of``."""
    return "; ".join(f"{h['shape']} ({h['words'].split(':')[0]}; explains {100 * h['explains']:.0f}% {of}, see "
                     f"{h['effect_file']})" for h in hs[:3])


def _why_undetermined(u: dict) -> str:
    """An undetermined calibration parameter's reason: its sd, or why it was not fitted at all."""
    return u["why"] if u.get("sd") is None else f"sd {u['sd']:.2g} {u['unit']}"


#: the summary names at most this many parameters of an effect (the rest: "… (+k more)")
SUMMARY_PARAMETERS = 4


def _is_payload(est: dict) -> bool:
    return "total_mass" in est and all(f"total_com_{a}" in est for a in "xyz")


def _payload_text(est: dict, rep: dict) -> str:
    """``tool_gravity`` as a user thinks of the tool: everything beyond the sensor (its mass and
    centre of mass, mm), the declared mass beside it and the difference, and where the added mass sits."""
    tm, com = est["total_mass"], [est[f"total_com_{a}"] for a in "xyz"]
    out = f"the whole tool {tm['value']:.4g} ± {tm['sd']:.2g} kg"
    if all(c["value"] is not None for c in com):
        out += (", centre of mass [" + ", ".join(f"{1000 * c['value']:.1f}" for c in com) + "] ± ["
                + ", ".join(f"{1000 * c['sd']:.2g}" for c in com) + "] mm")
    m0 = (rep.get("setup_summary") or {}).get("tool_mass_kg")
    dm = est["mass"]
    out += (f"; declared {m0:.4g} kg: " if m0 is not None else "; ") + f"{dm['value']:+.3g} ± {dm['sd']:.2g} kg"
    added = [est.get(f"com_{a}") or {} for a in "xyz"]
    if m0 and abs(dm["value"]) < 0.2 * m0:  # a correction of the declared tool, not a body added somewhere
        out += " (a correction of the declared tool)"
    elif all(a.get("value") is not None for a in added):
        out += " added at [" + ", ".join(f"{1000 * a['value']:.1f}" for a in added) + "] mm"
    return out


def _estimate_text(est: dict) -> str:
    """An effect's parameters for the summary: the ``SUMMARY_PARAMETERS`` largest by |value / sd|
    (the best-determined, so the largest is never hidden) in the estimate's own order, then how many
    are left out (``… (+2 more)``; diagnosis.json has them all)."""
    keys = [k for k in est if not k.startswith("total_") and est[k]["value"] is not None
            and not (k.startswith("first_moment_") and (est.get("com_" + k[-1]) or {}).get("value") is not None)]
    # (a first moment m c is the same parameter as its centre of mass: shown where the com is not defined)

    def z(k: str) -> float:
        v, sd = abs(float(est[k]["value"])), float(est[k]["sd"] or 0.0)
        return v / sd if sd > 0 else (math.inf if v > 0 else 0.0)

    shown = set(sorted(keys, key=z, reverse=True)[:SUMMARY_PARAMETERS])
    text = ", ".join(f"{k} {est[k]['value']:.3g} ± {est[k]['sd']:.2g} {est[k]['unit']}" for k in keys if k in shown)
    hidden = len(keys) - len(shown)
    return text + (f", … (+{hidden} more)" if hidden else "")


def _window_text(w: dict) -> str:
    """What part of a monitored run was judged, and what its baseline (the log before the onset) showed."""
    out = (f"From {w['from_s']:.2f} s (the monitor's event, '{w['event']}'; the log before its onset is the "
           "baseline, every effect below is judged on the log after it):")
    b = w.get("before") or {}
    if "not_diagnosed" in b:
        out += f" the baseline was not diagnosed ({b['not_diagnosed']})."
    elif b.get("present"):
        out += (f" before {b['to_s']:.2f} s the diagnosis names {', '.join(b['present'])} already (there before the "
                "change).")
    else:
        out += f" before {b['to_s']:.2f} s no library effect is present."
    if w.get("later_onsets_s"):
        out += " The monitor's later events from " + ", ".join(f"{v:.2f} s" for v in w["later_onsets_s"]) + \
            " fall inside the judged log."
    return out


def summary_text(rep: dict) -> str:
    """A paragraph a person reads first: the verdict on the model, then the effects."""
    chk = rep["sign_check"]
    if not chk["ok"]:
        return ("WARNING: " + chk["message"] + ". Every effect is 'cannot_decide' until the wrench convention "
                "is right (nothing can be judged against a tool that weighs less than nothing).")
    if rep.get("blocked"):
        return ("WARNING: " + rep["blocked"] + ". Every effect is 'cannot_decide' until the set-up is right "
                "(no effect can be judged against a model the data contradict at first sight).")
    parts = [completeness_text(rep)]  # the verdict on the model leads, whatever else is estimated
    if rep.get("window"):  # a monitored run: the log from the monitor's event on (``ownrun.monitor_window``)
        parts.insert(0, _window_text(rep["window"]))
    sm = rep.get("sensor_mount")
    if sm and not sm.get("mount_known", True):
        parts.append(_mount_text(rep, sm))
    if not rep["tip_contact_check"]["ok"]:
        parts.append("WARNING: " + rep["tip_contact_check"]["message"] + ".")
    if sm and sm.get("undetermined"):
        parts.append("Undetermined by this log's motion (the rest stands): " + "; ".join(
            f"{u['parameter']} ({_why_undetermined(u)}; to pin it: {u['to_pin']})" for u in sm["undetermined"]) + ".")
    seg = rep.get("segmentation")
    if seg and seg.get("contact_onsets_s"):
        parts.append(f"Free space found from the data: {seg['free_span_s'][0]:.2f}–{seg['free_span_s'][1]:.2f} s "
                     f"({seg['free_samples']} samples, the calibration's); contact from "
                     + ", ".join(f"{v:.2f} s" for v in seg["contact_onsets_s"]) + ".")
    cpt = (rep.get("effective_setup") or {}).get("contact_point")
    if cpt:
        parts.append(_contact_point_text(cpt))
    parts.extend(_accounts_text(rep))
    parts.extend(_verdicts_text(rep))
    parts.append(_spans_text(rep.get("method", {}).get("rows_cover_s") or {}))
    if "residual_rms_after" in rep:
        b, a = rep["residual_rms_before"]["total_w"], rep["residual_rms_after"]["total_w"]
        parts.append(f"With {', '.join(rep['added'])} added, the residual falls from {b:.3g} to {a:.3g} "
                     "(noise-weighted RMS, all rows)" + _effect_free_text(rep) + ".")
    return " ".join(p for p in parts if p)


def _mount_text(rep: dict, sm: dict) -> str:
    """The summary's sentence on an estimated sensor mount (and the tool, unless tool_gravity's
    entry gives it)."""
    com = sm["tool_com_sensor_m"]
    payload_said = any(e["effect"] == "tool_gravity" and e["verdict"] == "present" for e in rep["ranking"])
    return ("Sensor mount estimated: " + sm["paste"] + " (± " + ", ".join(f"{v:.2g}" for v in sm["sd_deg"])
            + f" deg; {sm['rotation_from_declared_deg']:.1f} deg from the guess)"
            + ("" if payload_said else  # the tool is said once: tool_gravity's entry gives it
               f"; tool {sm['tool_mass_kg']:.4g} ± {sm['tool_mass_sd_kg']:.2g} kg"
               + (", centre of mass [" + ", ".join(f"{1000 * v:.1f}" for v in com) + "] mm in the sensor frame"
                  if com[0] is not None else "")) + ".")


def _contact_point_text(cpt: dict) -> str:
    """The summary's sentence on the estimated contact point (``effective_setup.contact_point``)."""
    p, sd = cpt["point_sensor_m"], cpt["sd_m"]
    return ("Contacts act at [" + ", ".join(f"{1000 * v:.1f}" for v in p) + "] ± ["
            + ", ".join(f"{1000 * v:.1g}" for v in sd) + "] mm in the sensor frame"
            + (" (along the force's line of action, direction [" + ", ".join(
                f"{v:.2f}" for v in cpt["undetermined_along_sensor"]) + "], undetermined: the force "
               "barely changed direction)" if cpt["undetermined_along_sensor"] else "")
            + ("" if cpt["declared_tip_consistent"] else
               f", {1000 * cpt['declared_tip_distance_m']:.0f} mm from the declared tip") + ".")


def _verdicts_text(rep: dict) -> list[str]:
    """The summary's sentences on the effects, verdict by verdict: present (with their estimates),
    cannot decide, absent, not judged."""
    parts = _present_text(rep)
    und = [e for e in rep["ranking"] if e["verdict"] == "cannot_decide" and e.get("judged", True)]
    if und:
        parts.append("Cannot decide: " + "; ".join(
            f"{e['effect']} ({e.get('reason') or ''}"
            + (f"; {sel.tie_words(e['effect'], list(e.get('estimate', {})), e['indistinguishable_from'])}"
               if e.get("indistinguishable_from") else "")
            + (f"; undecided: {', '.join(e['undecided_parameters'])}" if e.get("undecided_parameters")
               and not e.get("indistinguishable_from") else "")
            + ")" for e in und) + ".")
    absent = [e["effect"] for e in rep["ranking"] if e["verdict"] == "absent"]
    if absent:
        parts.append("Absent (intervals inside their relevant sizes): " + ", ".join(absent) + ".")
    nj = [e["effect"] for e in rep["ranking"] if not e.get("judged", True)]
    if nj:
        parts.append("Not judged (no contact geometry declared): " + ", ".join(nj) + ".")
    return parts


def _present_text(rep: dict) -> list[str]:
    """The summary's sentences on the present effects: their estimates, what they explain, and the
    caution when the model stays incomplete."""
    pres = [e for e in rep["ranking"] if e["verdict"] == "present"]
    if not pres:
        return ["No library effect is present."]
    txt = []
    for e in pres:
        est = e["estimate"]
        txt.append(f"{e['effect']} ({_payload_text(est, rep) if _is_payload(est) else _estimate_text(est)})")
    parts = ["Present: " + "; ".join(txt) + f" — together {100 * rep['explained_by_present']:.0f}% of the "
             "residual of the declared model, held-out."]
    if not rep.get("model_complete", True):
        parts.append("Caution: the model stays incomplete, so these may stand in for part of what is unexplained.")
        left = next((e["estimate_params"]["left_rows"] for e in pres if "left_rows" in e.get("estimate_params", {})),
                    None)
        if left:  # completeness.robust
            parts.append(f"Their estimates leave out the rows of {', '.join(left)}, which carry it; each ± "
                         "includes the change this makes where the other rows pin the parameter "
                         "(diagnosis.json: left_sd, left_undetermined).")
    return parts


def _effect_free_text(rep: dict) -> str:
    lv = rep.get("effect_free_level")
    if not lv:
        return ""
    if lv.get("under_noise_floor"):
        return (f"; the effect-free run {lv['baseline']} leaves {lv['residual_rms_total_w']:.3g}: both under the "
                f"noise floor the rows are weighted by (1), below which the diagnosis resolves nothing "
                f"({lv['after_over_effect_free']:.2f}x the effect-free run's)")
    return (f"; the effect-free run {lv['baseline']} leaves {lv['residual_rms_total_w']:.3g}: "
            f"{lv['after_over_effect_free']:.2f}x the effect-free level")


def _nuisance_text(s: sg.LogSignals) -> str:
    parts = (["constant offset (tared log)"] if s.setup.log.tared else []) + (
        ["the tip's position (tip_known = false)"] if tip_nuisance(s) else [])
    return "; ".join(parts) or "none"


def _accounts_text(rep: dict) -> list[str]:
    """The tool's tip where the data put it, and the contact account where the two accounts disagree."""
    out = []
    tt = (rep.get("effective_setup") or {}).get("tool_tip")
    if tt:
        out.append("The tool's tip, fitted with the effects ([tool] tip_known = false): ["
                   + ", ".join(f"{1000 * v:.2f}" for v in tt["tip_sensor_m"]) + "] ± ["
                   + ", ".join(f"{1000 * e:.2g}" for e in tt["sd_m"]) + "] mm, "
                   + ", ".join(f"{a} {1000 * v:+.2f}" for a, v in zip("xyz", tt["difference_m"]))
                   + " mm from the declared first guess; contact effects are judged at it.")
    acc = (rep.get("contact") or {}).get("accounts")
    if acc and acc.get("disputed_windows_s") and ";" in acc.get("used", ""):
        out.append("Free space and contact: " + acc["used"] + ".")
    rel = (rep.get("contact") or {}).get("releases")
    if rel and rel.get("t_s"):
        late = [d - t for t, d in zip(rel["t_s"], rel["declared_release_t_s"])]
        out.append(f"The declared socket's releases the data show ({len(rel['t_s'])}, at "
                   + ", ".join(f"{t:.2f}" for t in rel["t_s"]) + " s) are rows of the fit: the declared tip's depth "
                   "there (the declared socket, from the encoders, releases at " + ", ".join(f"{d:+.2f}" for d in late)
                   + " s from them).")
    return out


def _spans_text(cov: dict) -> str:
    """A long log ranked on spans (``method.rows_cover_s``) in words; "" when every row time was used."""
    m = int(cov.get("span_every", 1))
    if m == 1:
        return ""
    nth = f"{m}{ {1: 'st', 2: 'nd', 3: 'rd'}.get(m % 10 if m % 100 not in (11, 12, 13) else 0, 'th')}"
    return (f"A long log: ranked on every {nth} {cov['span_s']:g} s span ({cov['covered_s']:.0f} s of "
            f"{cov['of_s']:.0f} s, spread over the whole log).")
