"""The woven yarn table through the disk cache: a hit equals the miss bit for bit, any changed input
misses, the medium's Mie optics are computed once per run (and not at all on a hit), the surface
albedo once per process.

Each test uses its own cache directory (``FABRIC_OPTICS_CACHE_DIR``); the root conftest keeps the
suite off the user's cache anyway.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from simulate import fiber as F
from simulate import raytrace as W
from simulate.fiber import tablecache as tc
from simulate.media.medium import HGMedium, MieMedium
from simulate.raytrace import materials as M
from simulate.raytrace import yarn as Y

_SMALL = dict(w_t_nodes=(0.0, 0.5), n_v=1, n_mu=3, n_phi=4, photons_per_row=2000)


@pytest.fixture
def cache(cache_dir):
    """The root conftest's own empty cache directory for this test."""
    return cache_dir


def _fiber(**medium):
    return F.Fiber(10.0, 1.5, HGMedium(**{"mu_s": 0.8, "mu_a": 0.01, "g": 0.5, **medium}), 0.3, 30.0)


def _fields(t):
    return {name: getattr(t, name) for name in ("T", "c_bar", "tau", "w_t_nodes")}


def test_hit_is_bit_identical_to_the_miss_and_to_an_uncached_build(cache):
    fib = _fiber()
    miss = W.yarn_table(fib, [500.0, 600.0], seed=5, threads=1, **_SMALL)
    hit = W.yarn_table(fib, [500.0, 600.0], seed=5, threads=2, **_SMALL)   # threads are not in the key
    off = W.yarn_table(fib, [500.0, 600.0], seed=5, threads=1, cache=False, **_SMALL)
    assert (miss.cache, hit.cache, off.cache) == ("miss", "hit", "off")
    assert hit.photons == miss.photons
    for name, a in _fields(miss).items():
        assert a.dtype == getattr(hit, name).dtype
        assert a.tobytes() == getattr(hit, name).tobytes(), name
        assert a.tobytes() == getattr(off, name).tobytes(), name
    assert len(tc.entries()) == 1


@pytest.mark.parametrize("change", ["seed", "medium", "wavelengths", "photons", "grid", "radius", "rough boundary"])
def test_a_changed_input_misses(cache, change):
    fib = _fiber()
    kw = dict(_SMALL, seed=5)
    W.yarn_table(fib, [550.0], threads=1, **kw)
    wl = [550.0]
    if change == "seed":
        kw["seed"] = 6
    elif change == "medium":
        fib = _fiber(mu_a=0.011)
    elif change == "wavelengths":
        wl = [551.0]
    elif change == "photons":
        kw["photons_per_row"] = 2002
    elif change == "grid":
        kw["n_phi"] = 5
    elif change == "radius":
        fib = dataclasses.replace(fib, radius_um=11.0)
    elif change == "rough boundary":
        fib = dataclasses.replace(fib, transmission_roughness=0.2)
    again = W.yarn_table(fib, wl, threads=1, **kw)
    assert again.cache == "miss"
    assert len(tc.entries()) == 2


def test_no_cache_environment_computes_every_time(cache, monkeypatch):
    monkeypatch.setenv(tc.ENV_DISABLE, "1")
    t = W.yarn_table(_fiber(), [550.0], seed=5, threads=1, **_SMALL)
    assert t.cache == "off" and not cache.exists()


def _mie_fiber():
    medium = MieMedium(n_host=1.5, particle_n=1.33, particle_k=1e-4, radius_um=0.3, volume_fraction=0.01,
                       phase_table_size=64)
    return F.Fiber(10.0, 1.5, medium, 0.3, 30.0)


def test_mie_optics_once_per_run_and_not_on_a_hit(cache, monkeypatch):
    calls = []
    real = Y.spectral_optics

    def counting(fiber, wl):
        calls.append(1)
        return real(fiber, wl)

    monkeypatch.setattr(Y, "spectral_optics", counting)
    fib = _mie_fiber()
    grid = {k: v for k, v in _SMALL.items() if k != "photons_per_row"}
    a, b = W.table_halves(fib, [500.0, 600.0], 1000, seed=2, threads=1, **grid)
    assert len(calls) == 1 and (a.cache, b.cache) == ("miss", "miss")
    assert a.T.tobytes() != b.T.tobytes()                      # independent halves
    a2, b2 = W.table_halves(fib, [500.0, 600.0], 1000, seed=2, threads=1, **grid)
    assert len(calls) == 1 and (a2.cache, b2.cache) == ("hit", "hit")
    assert a2.T.tobytes() == a.T.tobytes() and b2.T.tobytes() == b.T.tobytes()


def test_surface_albedo_once_per_process(cache, monkeypatch):
    calls = []
    real = M.microfacet.directional_albedo

    def counting(*args, **kw):
        calls.append(1)
        return real(*args, **kw)

    monkeypatch.setattr(M.microfacet, "directional_albedo", counting)
    M._albedo.cache_clear()
    first = M.surface_albedo(0.27, 1.53)
    first[0] = -1.0                                     # a caller's copy: the shared table is untouched
    second = M.surface_albedo(0.27, 1.53)
    assert len(calls) == 1 and second[0] != -1.0 and second.shape == (M.ALBEDO_NODES,)
    M._albedo.cache_clear()                             # a new process: from the disk cache, not recomputed
    third = M.surface_albedo(0.27, 1.53)
    assert len(calls) == 1 and third.tobytes() == second.tobytes()
    assert np.all(M.surface_albedo(0.0, 1.53) == 0.0)


_WARM_PROCESS = """
import sys
from simulate import fiber as F
from simulate import raytrace as W
from simulate.media.medium import MieMedium
medium = MieMedium(n_host=1.5, particle_n=1.33, particle_k=1e-4, radius_um=0.3, volume_fraction=0.01,
                   phase_table_size=64)
fib = F.Fiber(10.0, 1.5, medium, 0.3, 30.0)
a, b = W.table_halves(fib, [500.0, 600.0], 1000, seed=2, threads=1, w_t_nodes=(0.0, 0.5), n_v=1, n_mu=3, n_phi=4)
print(a.cache, b.cache, "miepython" in sys.modules)
"""


def test_a_warm_process_never_imports_miepython(cache):
    """miepython's import compiles a kernel (1-2 s): a process whose tables are cached does without it."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    env = {**os.environ, tc.ENV_DIR: str(cache), "PYTHONPATH": str(Path(__file__).resolve().parents[3])}
    outs = [subprocess.run([sys.executable, "-c", _WARM_PROCESS], env=env, capture_output=True, text=True,
                           timeout=900, check=True).stdout.split() for _ in range(2)]
    assert outs[0] == ["miss", "miss", "True"]
    assert outs[1] == ["hit", "hit", "False"]


def test_the_tables_rows_are_the_per_node_rows_bit_for_bit(cache):
    """The table's means are written straight into its wavelength groups' slices: each node's rows equal
    :func:`simulate.fiber.bssrdf.bssrdf_rows` of that node (its own sums and division) bit for bit, for a
    medium whose scattering splits the wavelengths into several groups."""
    from simulate.fiber.bssrdf import bssrdf_rows
    from simulate.fiber.spectral import group_walk, spectral_optics, wavelength_groups
    from simulate.montecarlo.transport import make_control

    medium = MieMedium(n_host=1.5, particle_n=2.7, particle_k=0.0, radius_um=0.1, volume_fraction=0.003,
                       phase_table_size=64)
    fib = F.Fiber(10.0, 1.5, medium, 0.3, 30.0)
    wl = np.array([420.0, 520.0, 620.0, 700.0])
    grid = dict(w_t_nodes=(0.0, 0.5), n_v=2, n_mu=3, n_phi=4)
    tab = W.yarn_table(fib, wl, seed=9, threads=1, photons_per_row=1500, cache=False, **grid)
    optics = spectral_optics(fib, wl)
    groups = wavelength_groups(optics)
    assert len(groups) >= 2
    n_psi, n_v, n_mu, n_phi = tab.n_psi, 2, 3, 4
    ks = list(range(tab.T.shape[1]))
    for j, w_t in enumerate((0.0, 0.5)):
        for g in groups:
            med, phase, targets = group_walk(fib, optics, g, white=True)
            ref, _, _, _ = bssrdf_rows(fib, w_t, ks, (n_psi, n_v, 2.0 * fib.radius_um, n_mu, n_phi), med, phase,
                                       targets, make_control(), 1500, 9 + 104729 * j, 1)
            got = tab.T[j][..., int(g[0]):int(g[-1]) + 1]
            assert got.tobytes() == ref.reshape(got.shape).tobytes()


def test_halves_read_side_by_side_and_a_felt_run_on_two_threads_are_the_serial_ones(cache, monkeypatch):
    """The cached halves are read on two threads (``threads`` not 1) and the second half's scene and table
    arrays built on another thread while the first half traces: the tables are the ones read one after the
    other, bit for bit, and a felt's ``fabric_beta`` the one of a single thread."""
    from simulate.fabric import structure as ST
    from simulate.geometry.felt import felt_mesh
    from simulate.raytrace import integrator as I

    fib = _fiber()
    kw = dict(_SMALL, photons_per_row=1000)
    computed = W.table_halves(fib, [500.0, 600.0], seed=5, threads=1, **kw)
    loads: list = []
    load = tc.load

    def counted(key):
        loads.append(key)
        return load(key)

    monkeypatch.setattr(tc, "load", counted)
    serial = W.table_halves(fib, [500.0, 600.0], seed=5, threads=1, **kw)
    side = W.table_halves(fib, [500.0, 600.0], seed=5, threads=2, **kw)
    assert [t.cache for t in computed] == ["miss", "miss"] and [t.cache for t in side] == ["hit", "hit"]
    assert len(loads) == 4 and loads[:2] == loads[2:] and loads[0] != loads[1]
    for a, b, c in zip(computed, serial, side, strict=True):
        for name, x in _fields(a).items():
            assert x.tobytes() == getattr(b, name).tobytes() == getattr(c, name).tobytes(), name
    # a felt pair at two incidences: the first half's setup built first, the second's by integrator.prepare on
    # another thread
    spec = ST.StructureSpec(kind="nonwoven", felt_spread_deg=15.0, layers=3)
    meshes = (felt_mesh(spec, 10.0, seed=0), felt_mesh(spec, 10.0, seed=1))
    w_i = np.array([[0.3, 0.0, 0.954], [0.0, 0.5, 0.866], [0.3, 0.0, 0.954]])
    w_o = np.array([[0.0, 0.0, 1.0], [0.4, 0.1, 0.911], [0.2, -0.3, 0.933]])
    prepared: list = []
    prepare = I.prepare

    def watched(mesh, material, setups, **k):
        prepared.append(mesh)
        prepare(mesh, material, setups, **k)

    monkeypatch.setattr(W.estimate, "prepare", watched)
    one = W.fabric_beta(meshes, fib, w_i, w_o, [500.0, 600.0], target_rel_err=0.3, seed=2, threads=1,
                        tables=serial)
    assert prepared == []
    two = W.fabric_beta(meshes, fib, w_i, w_o, [500.0, 600.0], target_rel_err=0.3, seed=2, threads=2,
                        tables=serial)
    assert len(prepared) == 2 and prepared[0] is meshes[0] and prepared[1] is meshes[1]
    assert one[0].tobytes() == two[0].tobytes() and one[1].tobytes() == two[1].tobytes()
    assert np.all(one[0] > 0.0)
