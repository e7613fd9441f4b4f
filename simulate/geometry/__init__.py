r"""The geometry of the fibre assemblies the ray tracer walks: a woven micro-element and a nonwoven felt.

Both are periodic cells of fibre tubes (a weave's yarns, a felt's fibres) triangulated in one mesh
type, :class:`simulate.geometry.mesh.FabricMesh`, whose layout is the contract with the tracer
(:mod:`simulate.raytrace`; layout in :mod:`simulate.geometry.weave`'s docstring).

A woven fabric is a weave matrix (1 = warp over weft) whose yarn centre lines are periodic splines
(:mod:`.weave`, or a WIF drawdown: :mod:`.wif`); its yarns are triangulated as elliptic tubes
(:func:`simulate.geometry.mesh.mesh`). A nonwoven felt has no yarns and no weave: it is a web of staple
fibres laid at random and bonded mechanically (needle punching, which drives part of the fibres
towards the normal) or by an adhesive. Its model (:mod:`.felt`) is one random realisation of that web in
a periodic cell: straight (or crimped) fibre tubes with a given orientation distribution, deposited
one by one without interpenetrating; the tracer walks it with each fibre's own BSSRDF table
(docs/physics.md section 6).

Modules: :mod:`.weave` (the woven micro-element: matrix, centre lines, presets), :mod:`.wif` (WIF 1.1
drawdowns), :mod:`.mesh` (:class:`~simulate.geometry.mesh.FabricMesh` and the weave's tubes), :mod:`.felt`
(the felt's random fibre web), :mod:`.validation` (a flat plane and a straight yarn: the tracer's
validation geometries).
"""

__all__ = ["felt", "mesh", "validation", "weave", "wif"]
