"""Every registered BRDF model, through its own examples (worker/models/<model>.py ``examples``),
as pbrt tests every BxDF: reciprocity, non-negativity, energy conservation by quadrature, the C
kernel against the NumPy reference, and its JSON form round-tripping. A model added to
worker/models is tested here without a line added to this file."""
import numpy as np
import pytest

from worker import native
from worker.core.directions import get_tree
from worker.core.lighting import LeafLighting, node_lighting
from worker.core.render import MaterialTable, shade_points_numpy
from worker.models import models, parse_material
from worker.native.kernels import kernels

CASES = [(name, i, m) for name, cls in models().items() for i, m in enumerate(cls.examples())]
IDS = [f"{n}-{i}" for n, i, _ in CASES]


def _hemi(n, rng):
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    v[:, 2] = np.abs(v[:, 2])
    return v


def test_every_model_has_examples():
    for name, cls in models().items():
        assert cls.examples(), f"model {name!r} gives no examples to test"


@pytest.mark.parametrize("name,i,m", CASES, ids=IDS)
def test_reciprocity_and_non_negativity(name, i, m):
    rng = np.random.default_rng(i)
    wi, wo = _hemi(4000, rng), _hemi(4000, rng)
    f1, f2 = m.evaluate(wi, wo), m.evaluate(wo, wi)
    assert (f1 >= 0).all()
    # tables (srbf, curve) are bilinear in h, which is itself symmetric: exact too
    np.testing.assert_allclose(f1, f2, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("name,i,m", CASES, ids=IDS)
def test_energy_conservation(name, i, m):
    """Directional albedo ∫ f cosθi dωi ≤ 1 at four view angles (cosine-weighted Monte Carlo,
    400k samples: 2% slack for glossy lobes)."""
    rng = np.random.default_rng(1)
    n = 400_000
    u1, u2 = rng.random(n), rng.random(n)
    r, phi = np.sqrt(u1), 2 * np.pi * u2
    wi = np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1 - u1)], 1)
    for theta in (0.0, 30.0, 60.0, 80.0):
        t = np.radians(theta)
        a = (m.evaluate(wi, np.broadcast_to([np.sin(t), 0.0, np.cos(t)], wi.shape)) * np.pi).mean(0)
        assert a.max() <= 1.02, (name, theta, a)


@pytest.mark.parametrize("name,i,m", CASES, ids=IDS)
def test_json_round_trip(name, i, m):
    again = parse_material(m.model_dump(mode="json"))
    assert type(again) is type(m) and again == m


@pytest.mark.skipif(not native.available(), reason="C kernels not built")
@pytest.mark.parametrize("name,i,m", CASES, ids=IDS)
def test_kernel_matches_reference(bunny, name, i, m):
    """The C kernel branch a model names shades as its NumPy reference does. A model without a C
    branch renders through its NumPy ``specular_part`` on both backends, so there is nothing to
    compare: it is skipped, and a model that names a branch the library does not have fails."""
    packed = m.pack()
    if packed.kernel is None:
        pytest.skip(f"{name} has no C branch: both backends shade it with its NumPy reference")
    assert native.model_id(packed.kernel) >= 0, f"{name} names C branch {packed.kernel!r}, which the library lacks"
    scene, cuts = bunny
    tree = get_tree()
    nl, nw = node_lighting(*LeafLighting(scene.envmap, tree).leaf_radiance(33.0, 1.3), tree)
    rng = np.random.default_rng(i)
    vi = rng.choice(len(scene.mesh.vertices), 300, replace=False).astype(np.int32)
    n = scene.mesh.normals[vi]
    wo = np.array([0.3, 0.8, 3.0], np.float32) - scene.mesh.vertices[vi]
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    mats = MaterialTable([m.pack()])
    mat_of = np.zeros(len(vi), np.int32)
    a = kernels("native").shade_points(n, wo, vi, mat_of, cuts, nl, nw, tree, mats)
    b = shade_points_numpy(n, wo, vi, mat_of, cuts, nl, nw, tree, mats)
    assert b.max() > 0
    np.testing.assert_allclose(a, b, rtol=2e-4, atol=1e-6 * b.max())


def test_srbf_table_through_the_cached_basis_matches_the_direct_sum():
    """A fitted srbf's p(h) table comes from the basis cached at the table directions (one
    mat-mul per stroke); it must equal the direct sum over centres (models/srbf.py srbf_p)."""
    from worker.fit.basis import default_basis
    from worker.models.srbf import TABLE_CACHE_MIN_J, srbf_p, srbf_table
    from worker.models.table import hemisphere_table_dirs

    b = default_basis()
    assert b.J >= TABLE_CACHE_MIN_J
    rng = np.random.default_rng(3)
    coef = rng.gamma(0.5, 2.0, (b.J, 3))
    ref = srbf_p(hemisphere_table_dirs(), b.centers, b.bandwidths, coef)
    for _ in range(2):              # computed, then from the cache
        got = srbf_table(b.centers, b.bandwidths, coef)
        err = np.abs(got - ref).max() / np.abs(ref).max()
        assert err < 1e-5, f"cached-basis table differs from the direct sum by {err:.2e} (relative to its max)"


@pytest.mark.skipif(not native.available(), reason="C kernels not built")
def test_lobes_pack_only_the_lobes_that_reflect(bunny):
    """A paint fit leaves most of its fixed lobes at zero: only the others are packed (the kernel
    evaluates a pow() per packed lobe per cluster), the sharpest of them sets the refine radius,
    and the kernel still shades as the NumPy reference over every lobe."""
    from worker.models.lobes import Lobes

    m = Lobes(exponents=[2.0, 30.0, 300.0, 10000.0], gloss=[0.0, 0.05, 0.0, 0.0],
              directional_diffuse=[(0.1, 0.05, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)],
              albedo=(0.1, 0.1, 0.1))
    p = m.pack()
    assert p.params[3] == 2 and list(p.params[4:12:4]) == [2.0, 30.0]
    assert p.refine_radius == pytest.approx(Lobes(exponents=[30.0], gloss=[0.05], directional_diffuse=[(0, 0, 0)],
                                                  albedo=(0.1, 0.1, 0.1)).pack().refine_radius)
    scene, cuts = bunny
    tree = get_tree()
    nl, nw = node_lighting(*LeafLighting(scene.envmap, tree).leaf_radiance(33.0, 1.3), tree)
    vi = np.random.default_rng(3).choice(len(scene.mesh.vertices), 300, replace=False).astype(np.int32)
    wo = np.array([0.3, 0.8, 3.0], np.float32) - scene.mesh.vertices[vi]
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    mats = MaterialTable([p])
    mat_of = np.zeros(len(vi), np.int32)
    a = kernels("native").shade_points(scene.mesh.normals[vi], wo, vi, mat_of, cuts, nl, nw, tree, mats)
    b = shade_points_numpy(scene.mesh.normals[vi], wo, vi, mat_of, cuts, nl, nw, tree, mats)
    assert b.max() > 0
    np.testing.assert_allclose(a, b, rtol=2e-4, atol=1e-6 * b.max())
