"""The model side of the physical effects, written once for the diagnosis and the controller.

``contract.py`` is the public ``@effect`` form (``kinadapt_nn.diagnostics.effect``, a user's effects
file); ``builtin/`` holds the built-in effects, one module each, written in that form (``BUILTINS``);
``contact_model.py`` the declared socket's nominal wrench that four of them need. This layer sits
below ``features/`` (``tests/test_layout.py``): the controller's online columns are taken from the same
modules, and nothing here reaches the simulator, the runs or the diagnosis's pipeline.
"""
