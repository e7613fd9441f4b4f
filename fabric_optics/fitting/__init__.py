"""The inverse problem: config parameters fitted to a measured dataset (``simulate fit``).

:mod:`.driver` runs a fit by the classic or the summation model, :mod:`.mc` by the Monte Carlo
(output space mapping); :mod:`.problem` holds the objective, :mod:`.start` the start from the
measured colour, :mod:`.state` the resumable state, :mod:`.structure` and :mod:`.walk_threads` the
structured summation's walks.
"""
