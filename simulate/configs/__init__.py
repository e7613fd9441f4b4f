"""The shipped simulation configs: the presets ``simulate`` commands take by name (``*.toml``).

Read through :func:`simulate.config.load_config` (:func:`simulate.config.preset_names` lists them); the
``method-errors*.json`` files are the method-errors studies that ``--method auto`` reads
(:mod:`simulate.fabric.auto`).
"""
