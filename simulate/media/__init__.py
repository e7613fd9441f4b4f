"""Scattering media of a fiber: Mie particles in an absorbing host, or Henyey-Greenstein (:mod:`.medium`)."""
