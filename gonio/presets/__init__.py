"""Shipped presets, accepted by name wherever a path is.

The acquisition plans (``red-cotton.toml``, ``green-felt.toml``, ``quick.toml``) and the white
standard's calibration table (``spectralon.csv``).
"""
