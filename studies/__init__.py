"""Studies built on the models: the inverse problem (``simulate fit``), parameter sweeps, benchmarks.

The layer above :mod:`simulate` and :mod:`compare` (the only code besides ``compare`` itself that
imports ``compare``): :mod:`.fit` and :mod:`.paths` (TOML paths of a config), :mod:`.sweep`,
:mod:`.bench` (with :mod:`.bench_fiber` and :mod:`.bench_woven`). The ``simulate`` command
line runs them.
"""
