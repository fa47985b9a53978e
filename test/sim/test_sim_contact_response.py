"""Property tests of the contact pressure model and the base taxel response."""
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from tacforce_ros.sim.contact import Contact, PressureModel, skin_surface
from tacforce_ros.sim.scene import Plate
from tacforce_ros.sim.taxel_response import (ResponseParams, counts_from_loads, taxel_loads,
                                             to_uint16)
from tacforce_ros.sim.vector import add3, cross, cross3, dot3, matTvec3, matvec3, scale3, sub3

PLATES = [Plate('button', 'sphere', 0.002), Plate('flat', 'plane', 0.0),
          Plate('edge', 'cylinder', 0.0008), Plate('convex', 'sphere', 0.025)]


def contact_on(array, taxel, normal_force, shear=(0.0, 0.0)):
    rotation = array.rotations[taxel]
    force = normal_force * rotation[:, 2] + shear[0] * rotation[:, 0] + shear[1] * rotation[:, 1]
    return Contact(force, array.positions[taxel], rotation[:, 2], rotation[:, 0], True)


@settings(max_examples=80, deadline=None)
@given(taxel=st.integers(0, 29), height=st.floats(-0.005, 0.005),
       tangent=st.tuples(st.floats(-0.002, 0.002), st.floats(-0.002, 0.002)),
       array_name=st.sampled_from(['index_tip', 'index_middle', 'palm_center']))
def test_skin_surface_puts_a_point_on_the_skin_with_the_skin_normal(hand, taxel, height, tangent,
                                                                    array_name):
    array = hand.array(array_name)
    taxel %= array.n_taxels
    normals = array.rotations[:, :, 2]
    rotation = array.rotations[taxel]
    near = (array.positions[taxel] + height * rotation[:, 2] + tangent[0] * rotation[:, 0]
            + tangent[1] * rotation[:, 1])
    point, normal = skin_surface(array.positions, normals, near)
    assert np.isclose(normal @ normal, 1.0)
    assert normal @ rotation[:, 2] > 0.9   # the normal of the skin there, not of elsewhere
    # Only the height above the skin is removed: the point moves along the normal.
    moved = near - point
    assert np.linalg.norm(moved - (moved @ normal) * normal) < 1e-12
    assert np.linalg.norm(moved) <= abs(height) + 0.001
    if np.allclose(normals, normals[0]):   # a flat array: exact
        assert np.allclose(point, near - height * rotation[:, 2], atol=1e-12)


def test_skin_surface_far_from_every_taxel_uses_the_nearest(hand):
    array = hand.array('index_tip')
    far = array.positions[3] + 1.0 * array.rotations[3][:, 2]
    point, normal = skin_surface(array.positions, array.rotations[:, :, 2], far)
    assert np.allclose(normal, array.rotations[3][:, 2])
    assert np.allclose(point, array.positions[3])


@settings(max_examples=60, deadline=None)
@given(plate=st.sampled_from(PLATES), taxel=st.integers(0, 29),
       force=st.floats(0.01, 50.0), array_name=st.sampled_from(['index_tip', 'index_middle']))
def test_weights_are_a_distribution_that_spreads_with_force(hand, plate, taxel, force,
                                                            array_name):
    array = hand.array(array_name)
    taxel %= array.n_taxels
    model = PressureModel(array.positions, plate)
    light = model.weights(contact_on(array, taxel, force))
    assert np.all(light >= 0) and np.isclose(light.sum(), 1.0)
    assert np.argmax(light) == taxel or light[taxel] >= 0.5 * light.max()
    heavy = model.weights(contact_on(array, taxel, force * 4.0))
    # Contact area grows with force: the load is no more concentrated than before.
    assert heavy.max() <= light.max() + 1e-12


def test_flat_plate_on_flat_array_loads_evenly_and_released_loads_nothing(hand):
    array = hand.array('index_middle')
    model = PressureModel(array.positions, PLATES[1])
    weights = model.weights(contact_on(array, 5, 2.0))
    assert np.allclose(weights, 1.0 / array.n_taxels, rtol=0.3)
    released = contact_on(array, 5, 2.0)
    released.active = False
    assert not model.weights(released).any()


@settings(max_examples=60, deadline=None)
@given(loads=st.lists(st.tuples(st.floats(-100, 100), st.floats(-100, 100),
                                st.floats(-100, 100)), min_size=1, max_size=30))
def test_response_is_bounded_monotone_and_ignores_tension(loads):
    local = np.array(loads)
    params = ResponseParams.nominal(len(local))
    rows = np.arange(len(local))
    counts = counts_from_loads(taxel_loads(local), params, rows)
    out = to_uint16(counts)
    assert out.dtype == np.uint16
    assert np.all(np.abs(counts - params.baseline) <= params.span + 1e-9)
    pressed = local.copy()
    pressed[:, 2] = np.abs(pressed[:, 2]) + 0.1
    more = counts_from_loads(taxel_loads(pressed), params, rows)
    less = counts_from_loads(taxel_loads(pressed * [1, 1, 0.5]), params, rows)
    assert np.all(more[:, 2] >= less[:, 2])
    unsaturated = pressed[:, 2] < 3.0
    assert np.all(more[unsaturated, 2] > less[unsaturated, 2])
    tension = local.copy()
    tension[:, 2] = -np.abs(tension[:, 2])
    assert np.allclose(counts_from_loads(taxel_loads(tension), params, rows)[:, 2],
                       params.baseline[:, 2])


finite = st.floats(-1e3, 1e3, allow_nan=False)
vec3 = st.tuples(finite, finite, finite)


@settings(max_examples=200, deadline=None)
@given(a=vec3, b=vec3, rows=st.tuples(vec3, vec3, vec3), scale=finite)
def test_float_vector_helpers_agree_with_numpy(a, b, rows, scale):
    va, vb, m = np.array(a), np.array(b), np.array(rows)
    tol = dict(rtol=1e-12, atol=1e-9)
    assert np.allclose(dot3(a, b), va @ vb, **tol)
    assert np.allclose(add3(a, b, scale), va + scale * vb, **tol)
    assert np.allclose(sub3(a, b), va - vb, **tol)
    assert np.allclose(scale3(scale, a), scale * va, **tol)
    assert np.allclose(cross3(a, b), np.cross(va, vb), **tol)
    assert np.allclose(cross(va, vb), np.cross(va, vb), **tol)
    assert np.allclose(matvec3(rows, b), m @ vb, **tol)
    assert np.allclose(matTvec3(rows, b), m.T @ vb, **tol)
