"""The live monitor: the diagnosis beside the controller (``kinadapt online --monitor``,
``kinadapt diagnose LOG --setup S --follow``; docs/monitor.md)."""

from kinadapt_nn.monitor.monitor import Event, Monitor, monitor_of_run

__all__ = ["Event", "Monitor", "monitor_of_run"]
