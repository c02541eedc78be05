"""The live monitor: the diagnosis beside the controller (``kinadapt online --monitor``,
``kinadapt diagnose LOG --setup S --follow``; docs/monitor.md).

``monitor`` (the ``Monitor`` and its events; importing it registers it with the episode loop),
``kernel`` (the per-sample numba kernel), ``shapes`` (naming an event), ``follow`` (a growing log),
``figure`` (the residual and the events).
"""
