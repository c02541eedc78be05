"""The built-in effects, one module each, written in the public form a user writes
(``kinadapt_nn.diagnostics.contract``). ``BUILTINS`` is the one registry both diagnosis paths
read their names from; add a module here and list it in ``_MODULES``."""

from __future__ import annotations

from kinadapt_nn.diagnostics.builtin import (encoder_offset, ft_bias_drift, ft_frame_rotation, ft_offset, tool_gravity,
                                             tool_inertia, tool_tilt)
from kinadapt_nn.diagnostics.contract import Effect, effects_of_module

_MODULES = (tool_gravity, tool_inertia, ft_bias_drift, ft_frame_rotation, encoder_offset, tool_tilt, ft_offset)

#: name -> Effect, in the order the report lists them
BUILTINS: dict[str, Effect] = {n: e for mod in _MODULES for n, e in effects_of_module(mod).items()}

def _contact_model_effects() -> tuple[str, ...]:
    from kinadapt_nn.features.effect_library import LIBRARY

    return tuple(n for n in LIBRARY if n not in BUILTINS)


#: the package-run library's effects that a user's log cannot judge (contact-model effects: they
#: need a declared contact geometry; judged on this package's own runs, ``kinadapt diagnose RUN``)
CONTACT_MODEL_EFFECTS = _contact_model_effects()

__all__ = ["BUILTINS", "CONTACT_MODEL_EFFECTS"]
