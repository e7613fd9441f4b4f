"""Optics of one interface and one particle: Fresnel, Cook-Torrance microfacets, phase functions, Mie.

The bottom layer of :mod:`simulate` (imports nothing of it above): :mod:`.fresnel`,
:mod:`.microfacet` (the one Cook-Torrance: numpy for the models, compiled helpers for the
Monte Carlo tracers), :mod:`.phase` (tabulated phase functions), :mod:`.mie` (spheres and
size distributions).
"""
