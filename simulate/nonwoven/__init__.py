r"""Nonwoven fabrics: a felt built as geometry and traced by the fabric Monte Carlo.

A nonwoven felt has no yarns and no weave: it is a web of staple fibres laid at random and bonded
mechanically (needle punching, which drives part of the fibres towards the normal) or by an
adhesive. Its model here (:mod:`simulate.nonwoven.felt`) is one random realisation of that web in a
periodic cell: straight (or crimped) fibre tubes with a given orientation distribution, deposited
one by one without interpenetrating. The mesh follows the weave mesh's contract, so the same tracer
(:mod:`simulate.woven`) walks it with each fibre's own BSSRDF table (docs/physics.md section 6).
"""

__all__ = ["felt"]
