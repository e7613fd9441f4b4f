"""The structured summation's walk: its exit tables scored at absorption nodes, one walk per lattice point.

:mod:`.walk` walks the layer tables of a config with ``[structure]`` (any dye read from them afterwards),
keyed in the table cache; :mod:`.threads` runs its independent ``(half, chunk)`` entries on threads.
``simulate fit`` (:mod:`fabric_optics.fitting`) evaluates the structured summation through it.
"""
