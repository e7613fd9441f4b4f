"""``simulate bench`` part 3.

The woven-fabric Monte Carlo -- ray engine speed, the red-cotton headline, and where the cheaper fabric models depart
from it.

* Ray engine: first-hit queries per second on the red-cotton micro-element, Embree (through
  ``embreex``, with the periodic wrap of :class:`simulate.raytrace.scene.PeriodicScene`) on one and two
  threads, against a compiled brute-force intersector (every triangle tested: what any hand-written
  acceleration structure must beat first), on the same rays (raw first hits, no wrap, for both).
* Headline (docs/quality.md): the red-cotton plan's in-plane curves (4 incidences x 14
  observations x 33 wavelengths) to 1 %, on all cores; wall time, rays, and the peak memory of
  the run (measured in a child process so that earlier parts of the bench do not count).
* Where methods differ: the summation and classic models at the same geometries, their ratio
  to the Monte Carlo reference against the observation angle, per incidence (chart).
"""

from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numba
import numpy as np

from fabric_optics.bench.method_errors import chart, departure, in_child, model_datasets

__all__ = ["ray_engine_speed", "red_cotton_mc", "run_woven_bench", "chart", "in_child"]


@numba.njit(cache=True)
def _brute_first_hit(tri, origins, directions):
    """First hit by testing every triangle (Moller-Trumbore, compiled): the no-acceleration baseline."""
    n = origins.shape[0]
    out = np.full(n, -1, np.int64)
    for i in range(n):
        best = 1e30
        ox, oy, oz = origins[i, 0], origins[i, 1], origins[i, 2]
        dx, dy, dz = directions[i, 0], directions[i, 1], directions[i, 2]
        for f in range(tri.shape[0]):
            e1x = tri[f, 1, 0] - tri[f, 0, 0]
            e1y = tri[f, 1, 1] - tri[f, 0, 1]
            e1z = tri[f, 1, 2] - tri[f, 0, 2]
            e2x = tri[f, 2, 0] - tri[f, 0, 0]
            e2y = tri[f, 2, 1] - tri[f, 0, 1]
            e2z = tri[f, 2, 2] - tri[f, 0, 2]
            px = dy * e2z - dz * e2y
            py = dz * e2x - dx * e2z
            pz = dx * e2y - dy * e2x
            det = e1x * px + e1y * py + e1z * pz
            if abs(det) < 1e-12:
                continue
            inv = 1.0 / det
            tx = ox - tri[f, 0, 0]
            ty = oy - tri[f, 0, 1]
            tz = oz - tri[f, 0, 2]
            u = (tx * px + ty * py + tz * pz) * inv
            if u < 0.0 or u > 1.0:
                continue
            qx = ty * e1z - tz * e1y
            qy = tz * e1x - tx * e1z
            qz = tx * e1y - ty * e1x
            v = (dx * qx + dy * qy + dz * qz) * inv
            if v < 0.0 or u + v > 1.0:
                continue
            t = (e2x * qx + e2y * qy + e2z * qz) * inv
            if 0.0 < t < best:
                best = t
                out[i] = f
    return out


def _rays(mesh: Any, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    mu = np.sqrt(rng.uniform(0.05, 1.0, n))
    phi = rng.uniform(0, 2 * np.pi, n)
    d = -np.column_stack([np.sqrt(1 - mu ** 2) * np.cos(phi), np.sqrt(1 - mu ** 2) * np.sin(phi), mu])
    o = np.column_stack([rng.uniform(0, mesh.Lx, n), rng.uniform(0, mesh.Ly, n), np.full(n, mesh.z_max + 1.0)])
    return o, d


def ray_engine_speed(mesh: Any, n_rays: int = 200_000, repeats: int = 3, alternative_rays: int = 20_000) -> dict:
    """Rays per second: Embree with wrap (1 and 2 threads), raw Embree and trimesh on the same rays."""
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    from simulate.raytrace.scene import PeriodicScene

    scene = PeriodicScene(mesh.vertices, mesh.faces, mesh.Lx, mesh.Ly)
    o, d = _rays(mesh, n_rays, 1)
    scene.intersect(o[:1000], d[:1000])

    def wrapped(k: int) -> float:
        parts = np.array_split(np.arange(n_rays), k)
        t = time.perf_counter()
        if k == 1:
            scene.intersect(o, d)
        else:
            with ThreadPoolExecutor(k) as pool:
                list(pool.map(lambda idx: scene.intersect(o[idx], d[idx]), parts))
        return n_rays / (time.perf_counter() - t)

    one = [wrapped(1) for _ in range(repeats)]
    two = [wrapped(2) for _ in range(repeats)]
    raw = rtcore_scene.EmbreeScene()
    TriangleMesh(raw, mesh.vertices.astype(np.float32), mesh.faces.astype(np.int32))
    o32, d32 = o.astype(np.float32), d.astype(np.float32)
    raw_rates = []
    for _ in range(repeats):
        t = time.perf_counter()
        raw.run(o32, d32, output=1)
        raw_rates.append(n_rays / (time.perf_counter() - t))
    m = min(alternative_rays, n_rays)
    tri = np.ascontiguousarray(mesh.vertices[mesh.faces])
    _brute_first_hit(tri, o[:10], d[:10])   # compile
    t = time.perf_counter()
    first_alt = _brute_first_hit(tri, o[:m], d[:m])
    alt_rate = m / (time.perf_counter() - t)
    first_embree = raw.run(o32[:m], d32[:m])
    agree = float(np.mean(first_alt == first_embree))
    return {"triangles": int(mesh.faces.shape[0]), "rays": n_rays,
            "embree_wrapped_one_thread_median": float(np.median(one)),
            "embree_wrapped_two_threads_median": float(np.median(two)),
            "speedup_two_threads": float(np.median(two) / np.median(one)),
            "embree_raw_median": float(np.median(raw_rates)),
            "brute_force_rays_per_s": alt_rate, "brute_force_rays": m,
            "embree_over_brute_force": float(np.median(raw_rates) / alt_rate),
            "first_hits_agree_fraction": agree}


def red_cotton_mc(target: float = 0.01) -> dict:
    """The headline run in a child process (its own peak memory); returns figures and the table."""
    return in_child(target)


def run_woven_bench(target: float = 0.01) -> dict:
    """All three parts (minutes)."""
    from simulate.config import load_config, weave_from_config
    from simulate.geometry.mesh import mesh as weave_mesh

    mesh = weave_mesh(weave_from_config(load_config("red-cotton")))
    report: dict[str, Any] = {"machine": {"cpus": os.cpu_count()}, "target": target,
                              "ray_engine": ray_engine_speed(mesh)}
    report["red_cotton"] = red_cotton_mc(target)
    report["models"] = model_datasets()
    report["departure"] = departure(report)
    report["cost_growth"] = cost_growth()
    return report


def markdown(report: dict) -> str:
    """Headline figures as a markdown table."""
    e = report["ray_engine"]
    rc = report["red_cotton"]
    info = rc["info"]
    lines = [
        "| figure | value |", "|---|---|",
        f"| Embree first hits with periodic wrap, 1 thread (median) | {e['embree_wrapped_one_thread_median'] / 1e6:.2f} M rays/s |",
        f"| same, 2 threads | {e['embree_wrapped_two_threads_median'] / 1e6:.2f} M rays/s ({e['speedup_two_threads']:.2f}x) |",
        f"| Embree raw / compiled brute force, no acceleration structure (same rays) | "
        f"{e['embree_raw_median'] / 1e6:.2f} M / {e['brute_force_rays_per_s'] / 1e3:.1f} k rays/s "
        f"({e['embree_over_brute_force']:.0f}x; first hits agree {e['first_hits_agree_fraction']:.4f}) |",
        f"| red cotton 4 x 14 x 33 to 1 %: wall | {rc['wall_seconds']:.1f} s (table {info['table']['seconds']:.1f} s "
        f"CPU, {info['rays']} rays) |",
        f"| achieved rel_err (rms of u / each direction's spectral peak) | {rc['rel_err']:.2%} |",
        f"| peak memory of the run | {rc['peak_rss_mb']:.0f} MB |",
    ]
    for name, d in report["departure"].items():
        lines.append(f"| {name} vs MC: departure (rms over wavelengths, of the MC peak), median / max over geometries | "
                     f"{d['median_rms_departure']:.1%} / {d['max_rms_departure']:.1%} |")
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------
# cost growth (speed against accuracy: fabric_optics.bench.speed_accuracy)
# ------------------------------------------------------------------------------------------


def _plan_subset(plan: Any, wavelengths: Any) -> Any:
    """The plan with only ``wavelengths`` (cost growth with the number of wavelengths)."""
    import dataclasses

    return dataclasses.replace(plan, wavelengths_nm=np.asarray(wavelengths, float))


def cost_growth(target: float = 0.02) -> dict:
    """Woven Monte Carlo wall time against the number of wavelengths and of threads (red cotton)."""
    from gonio.acquisition.plan import load_plan
    from simulate.config import load_config
    from simulate.virtual import fabric_dataset

    cfg = load_config("red-cotton")
    plan = load_plan("red-cotton")
    wl = np.asarray(plan.wavelengths_nm, float)
    rows = []
    for n in (3, 11, 33):
        sub = _plan_subset(plan, wl[np.linspace(0, wl.size - 1, n).round().astype(int)])
        for threads in (1, 2):
            t = time.perf_counter()
            ds = fabric_dataset(cfg, sub, "mc", target_rel_err=target, threads=threads)
            info = ds.meta["provenance"]["fiber_info"]
            rows.append({"wavelengths": n, "threads": threads, "seconds": time.perf_counter() - t,
                         "table_cpu_seconds": info["table"]["seconds"], "rays": info["rays"]})
    return {"target": target, "runs": rows}


def chart_cost_growth(report: dict, path: Path) -> None:
    """Woven Monte Carlo wall time against the number of wavelengths, per thread count."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, b = plt.subplots(figsize=(5.5, 4.2))
    cg = report["cost_growth"]["runs"]
    for threads, marker in ((1, "o-"), (2, "s-")):
        r = [x for x in cg if x["threads"] == threads]
        b.plot([x["wavelengths"] for x in r], [x["seconds"] for x in r], marker, label=f"{threads} thread(s)")
    b.set_xlabel("wavelengths")
    b.set_ylabel("wall time (s)")
    b.set_title(f"woven MC cost growth (target {report['cost_growth']['target']:.0%})")
    b.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
