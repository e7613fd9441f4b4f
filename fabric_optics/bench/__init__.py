"""Benchmarks (``simulate bench``): speed against error of the kernel, the fiber, the fabric methods.

:mod:`.suite` is the benchmark ``simulate bench`` runs; the other modules are its parts and the
studies it draws on (:mod:`.method_errors`: where each method fails).
"""
