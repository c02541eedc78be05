"""The built-in effects, one module each, written in the public form a user writes
(``kinadapt_nn.effects.contract``). ``BUILTINS`` is the one registry the diagnosis reads and the
controller's online library is derived from (``features.effect_library.LIBRARY``: those with an
``online`` side); add a module here and list it in ``_MODULES``."""

from __future__ import annotations

from kinadapt_nn.effects.builtin import (contact_friction_couple, contact_stiffness, encoder_offset, ft_bias_drift,
                                             ft_frame_rotation, ft_offset, grasp_compliance, tool_gravity, tool_inertia,
                                             tool_tilt)
from kinadapt_nn.effects.contract import Effect, effects_of_module

_MODULES = (tool_gravity, tool_inertia, ft_bias_drift, ft_frame_rotation, encoder_offset, tool_tilt, ft_offset,
            contact_stiffness, contact_friction_couple, grasp_compliance)

#: name -> Effect, in the order the report lists them
BUILTINS: dict[str, Effect] = {n: e for mod in _MODULES for n, e in effects_of_module(mod).items()}


#: the contact-model effects: judged only where the set-up declares a contact geometry
#: (``[contact] geometry``, ``kinadapt_nn.effects.contact_model``); listed as not judged otherwise
CONTACT_MODEL_EFFECTS: tuple[str, ...] = tuple(
    n for mod in (contact_stiffness, contact_friction_couple, grasp_compliance) for n in effects_of_module(mod))

__all__ = ["BUILTINS", "CONTACT_MODEL_EFFECTS"]
