"""The command lines ``gonio``, ``simulate`` and ``compare`` (console scripts of the distribution)."""
