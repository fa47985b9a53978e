"""The magnetic skin's physics, each piece against a case computed by hand, and the effect."""
import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import stack
from hypothesis import given, settings
from hypothesis import strategies as st

from tacforce_ros.sim import load_scene, make_simulator
from tacforce_ros.sim import skin_physics as phys
from tacforce_ros.sim.contact import Contact
from tacforce_ros.sim.elastomer_memory import Creep, Play
from tacforce_ros.sim.effects import Pipeline
from tacforce_ros.sim.effects import magnetic_skin
from tacforce_ros.sim.effects.magnetic_skin import CHIP_RANGE, MagneticSkin, SkinPlacementError
from tacforce_ros.sim.scene import Plate
from tacforce_ros.sim.taxel_response import CHIP_ZERO

MAGNETIC = {'magnetic_skin': {}}


def test_a_current_loop_at_its_centre_and_on_its_axis():
    a, current = 0.001, 2.0
    b_rho, b_z = phys.loop_field(a, current, np.array([0.0, 0.0]), np.array([0.0, 0.003]))
    np.testing.assert_allclose(b_rho, 0.0, atol=0.0)
    # mu0 I a^2 / (2 (a^2 + z^2)^(3/2)): 1.2566e-3 T at the centre, 3.974e-5 T 3 mm above it.
    np.testing.assert_allclose(b_z, [1.2566371e-3, 3.9738353e-5], rtol=1e-7)


@pytest.mark.parametrize('rho_over_a', [0.0, 1e-9, 1e-5, 2e-4, 0.3, 2.5])
def test_a_current_loops_field_off_its_axis_is_biot_savarts(rho_over_a):
    """Against dB = mu0 I / 4 pi dl x r / r^3 summed over 20 000 segments of the loop, on
    either side of it, on, near and far from its axis (near it B_rho is the axial series)."""
    a, current = 0.001, 2.0
    phi = (np.arange(20000) + 0.5) * 2 * np.pi / 20000
    wire = a * np.column_stack([np.cos(phi), np.sin(phi), np.zeros_like(phi)])
    dl = a * 2 * np.pi / 20000 * np.column_stack([-np.sin(phi), np.cos(phi), np.zeros_like(phi)])
    for z in (0.0024, -0.0007):
        point = np.array([rho_over_a * a, 0.0, z])
        r = point - wire
        field = phys.MU0 * current / (4 * np.pi) * np.sum(
            np.cross(dl, r) / np.linalg.norm(r, axis=1, keepdims=True) ** 3, axis=0)
        b_rho, b_z = phys.loop_field(a, current, np.array(point[0]), np.array(z))
        scale = np.abs(field).max()
        np.testing.assert_allclose([b_rho, b_z], field[[0, 2]], rtol=0, atol=1e-9 * scale)
        if 1e-6 < rho_over_a < 1e-3:    # B_rho itself, where the sum's rounding allows it
            np.testing.assert_allclose(b_rho, field[0], rtol=1e-6)


def test_a_cylinder_magnets_field_on_its_axis_is_the_closed_form():
    """B_z = B_r / 2 ((z + L/2) / sqrt((z + L/2)^2 + R^2) - (z - L/2) / sqrt((z - L/2)^2 + R^2))
    on either side, from one length beyond its face outwards (the chip reads nearer fields
    beyond its range); nothing across the axis."""
    remanence, diameter, length = 1.345, 0.002, 0.0005
    z = np.array([1.5, 2.0, 4.0, 8.0, 40.0]) * length
    ends = np.stack([z + length / 2, z - length / 2])
    closed = remanence / 2 * (ends[0] / np.hypot(ends[0], diameter / 2)
                              - ends[1] / np.hypot(ends[1], diameter / 2))
    for sign in (1.0, -1.0):
        offset = np.column_stack([np.zeros((len(z), 2)), sign * z])
        field = phys.cylinder_field(remanence, diameter, length, offset)
        np.testing.assert_allclose(field[:, 2], closed, rtol=1e-9)
        np.testing.assert_array_equal(field[:, :2], 0.0)
    # 2.4 mm below the centre of the shipped magnet: 19.42 mT, 0.80 of its point dipole's.
    np.testing.assert_allclose(phys.cylinder_field(remanence, diameter, length,
                                                   np.array([0.0, 0.0, -0.0024]))[2],
                               0.019422208, rtol=1e-7)


def test_far_from_a_cylinder_magnet_its_field_is_its_dipoles():
    """At 25 diameters, B = mu0 / 4 pi (3 r (m . r) / r^5 - m / r^3) with m = B_r V / mu0, to
    the octupole's (size / distance)^2."""
    remanence, diameter, length = 1.345, 0.002, 0.0005
    m = np.array([0.0, 0.0, remanence * np.pi * diameter ** 2 / 4 * length / phys.MU0])
    for direction in ([0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.6, -0.48, 0.64]):
        r = 0.05 * np.array(direction) / np.linalg.norm(direction)
        dipole = phys.MU0 / (4 * np.pi) * (3 * r * (m @ r) / np.linalg.norm(r) ** 5
                                            - m / np.linalg.norm(r) ** 3)
        np.testing.assert_allclose(phys.cylinder_field(remanence, diameter, length, r), dipole,
                                   rtol=0, atol=2e-3 * np.abs(dipole).max())


def test_a_neo_hookean_column_at_half_and_twice_its_length():
    """mu (lam - lam^-2) with mu = E / 3: at lam = 1/2 the nominal stress is -7/6 E, at lam = 2
    it is 7/12 E; a linear solid would be strained by those stresses over E."""
    np.testing.assert_allclose(phys.neo_hookean_stretch(np.array([-7 / 6, 7 / 12, 0.0])),
                               [0.5, 2.0, 1.0], rtol=1e-13)
    small = np.array([-1e-5, 1e-5])
    np.testing.assert_allclose(phys.neo_hookean_stretch(small), 1.0 + small, rtol=1e-9)


@settings(max_examples=300)
@given(strains=st.lists(st.floats(-1e3, 1e3), min_size=2, max_size=2))
def test_a_neo_hookean_column_solves_its_law_and_never_collapses(strains):
    strain = np.sort(np.asarray(strains))
    stretch = phys.neo_hookean_stretch(strain)
    assert np.all(stretch > 0.0) and stretch[0] <= stretch[1]
    np.testing.assert_allclose((stretch - stretch ** -2.0) / 3.0, strain,
                               rtol=1e-10, atol=1e-12)
    # Squeezed, it shortens less than the linear solid would (where that one keeps a length).
    assert np.all(stretch[strain < 0.0] >= 1.0 + strain[strain < 0.0])


def test_hertz_contact_radius_of_a_worked_example():
    """R 8 mm on a rigid plane, F = 60 pi N, E = 1000 MPa, nu = 0.3: a = 1.010 mm (the worked
    example beside the formula list of S. J. Bull, Newcastle University)."""
    e_star = 1000e6 / (1 - 0.3 ** 2)
    a, b = phys.hertz_semi_axes(60 * np.pi, (1 / 0.008, 1 / 0.008), e_star)
    assert a == b == pytest.approx(1.010e-3, abs=1e-6)


def test_an_elongated_contact_lies_along_the_smaller_curvature():
    """Against the exact Hertz ellipse: for semi-axes b < a, the curvature ratio is
    B / A = (E(e) / (1 - e^2) - K(e)) / (K(e) - E(e)), e^2 = 1 - (b/a)^2 (complete elliptic
    integrals of parameter e^2; Johnson 1985, ch. 4)."""
    from scipy.optimize import brentq
    from scipy.special import ellipe, ellipk

    def curvature_ratio(e):
        m = e * e
        return (ellipe(m) / (1.0 - m) - ellipk(m)) / (ellipk(m) - ellipe(m))

    e = brentq(lambda e: curvature_ratio(e) - 8.0, 1e-6, 1.0 - 1e-12)
    a, b = phys.hertz_semi_axes(1.0, (10.0, 80.0), 1e5)
    assert a > b and b / a == pytest.approx(np.sqrt(1.0 - e * e), rel=0.03)
    assert np.sqrt(a * b) == pytest.approx((3 / (4e5 * np.sqrt(800.0))) ** (1 / 3))


def test_the_patch_samples_the_hertz_pressure():
    """Unit load, and the pressure's second moment: int r^2 p dA / P = 2 a^2 / 5."""
    points, weights = phys.elliptic_patch(n_rings=40, n_spokes=16)
    assert weights.sum() == pytest.approx(1.0)
    assert weights @ np.sum(points ** 2, axis=1) == pytest.approx(0.4, rel=2e-3)


def _sphere(radius, n=200, seed=0):
    normals = np.random.default_rng(seed).normal(size=(n, 3))
    normals[:, 2] = np.abs(normals[:, 2]) + 1.0
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return radius * normals, normals


def test_skin_curvature_of_a_sphere_a_cylinder_and_a_plane():
    positions, normals = _sphere(0.0135)
    top = np.array([0.0, 0.0, 1.0])
    k = phys.skin_curvature(positions, normals, 0.0135 * top, top, reach=0.004)
    np.testing.assert_allclose(np.linalg.eigvalsh(k), [1 / 0.0135] * 2, rtol=0.02)
    grid = np.random.default_rng(1).uniform(-0.01, 0.01, (200, 2))
    angle = grid[:, 1] / 0.01       # a cylinder of radius 10 mm along x
    cyl_n = np.column_stack([np.zeros(200), np.sin(angle), np.cos(angle)])
    cyl_p = np.column_stack([grid[:, 0], 0.01 * cyl_n[:, 1], 0.01 * cyl_n[:, 2]])
    k = phys.skin_curvature(cyl_p, cyl_n, 0.01 * top, top, reach=0.004)
    np.testing.assert_allclose(np.linalg.eigvalsh(k), [0.0, 100.0], atol=1.0)
    flat = np.column_stack([grid, np.zeros(200)])
    k = phys.skin_curvature(flat, np.tile(top, (200, 1)), np.zeros(3), top, reach=0.004)
    np.testing.assert_allclose(k, 0.0, atol=1e-12)



def test_skin_curvature_by_normal_equations_is_least_squares_and_a_line_of_taxels_falls_back():
    """The closed-form 2 x 2 solve gives lstsq's fit; taxels on a line (a rank-1 design) get
    lstsq's minimum-norm fit instead of a division by a vanishing determinant."""
    positions, normals = _sphere(0.0135, n=30, seed=3)
    top = np.array([0.0, 0.0, 1.0])
    basis = np.stack(phys.tangent_basis(top))
    offset, turn = (positions - 0.0135 * top) @ basis.T, (normals - top) @ basis.T
    weight = np.sqrt(np.exp(-0.5 * np.sum(offset ** 2, axis=1) / 0.004 ** 2))[:, None]
    fit, *_ = np.linalg.lstsq(weight * offset, weight * turn, rcond=None)
    np.testing.assert_allclose(phys.skin_curvature(positions, normals, 0.0135 * top, top, 0.004),
                               0.5 * (fit + fit.T), rtol=0.0, atol=1e-9 / 0.0135)
    angle = np.linspace(-0.3, 0.3, 7)           # taxels along one meridian of the sphere
    line_n = np.column_stack([np.sin(angle), np.zeros(7), np.cos(angle)])
    k = phys.skin_curvature(0.0135 * line_n, line_n, 0.0135 * top, top, reach=0.004)
    assert np.all(np.isfinite(k))
    along = basis @ np.array([1.0, 0.0, 0.0])   # the line's direction in the tangent basis
    assert along @ k @ along == pytest.approx(1 / 0.0135, rel=0.02)

def test_creep_and_play():
    creep = Creep(share=0.2, tau=1.0)
    creep.reset((1,), dt=0.01)
    out = [creep(np.array([1.0]))[0] for _ in range(100)]
    assert out[0] == pytest.approx(1.0 + 0.2 * (1 - np.exp(-0.01)))
    assert out[-1] == pytest.approx(1.0 + 0.2 * (1 - np.exp(-1.0)))
    play = Play(relative=0.05, width=0.0)
    play.reset((1,))
    up = [play(np.array([v]))[0] for v in np.linspace(0, 2, 21)]
    down = [play(np.array([v]))[0] for v in np.linspace(2, 0, 21)]
    assert up[10] == pytest.approx(0.95)     # rising: lags 5 % of the input below it
    assert down[10] == pytest.approx(1.05)   # falling: holds 5 % above
    with pytest.raises(ValueError):
        Creep(share=-0.1, tau=1.0)


@pytest.fixture(scope='module')
def skin(hand):
    def make(array='index_middle', **params):
        effect = MagneticSkin(**params)
        arr = hand.array(array)
        array_of = np.empty(hand.n_taxels, np.int64)
        for index, each in enumerate(hand.arrays):
            array_of[each.flat_indices] = index
        ctx = SimpleNamespace(hand=hand, n_taxels=hand.n_taxels, array=arr,
                              rows=arr.flat_indices, array_of_taxel=array_of, dt=0.01)
        effect.draw_hand(np.random.default_rng(0), ctx)
        effect.reset(np.random.default_rng(0), ctx)
        centre = np.argmin(np.linalg.norm(arr.positions - arr.positions.mean(0), axis=1))
        return effect, arr, centre
    return make


def test_rest_readings_span_the_measured_ranges(skin):
    effect, _, _ = skin()
    rest = effect.rest_counts
    # The magnets sit where their fields read the drawn rest values, to rounding.
    assert 33600 - 1e-6 <= rest[:, 2].min() and rest[:, 2].max() <= 37600 + 1e-6
    assert np.abs(rest[:, :2] - CHIP_ZERO).max() <= 1350 + 1e-6
    assert np.ptp(rest[:, 2]) > 3000 and np.ptp(rest[:, :2]) > 2000
    lateral, height = effect.placement(rest)
    np.testing.assert_allclose(height, effect.height, rtol=1e-9)
    np.testing.assert_allclose(lateral, effect.lateral, atol=1e-12)


def test_a_magnet_is_placed_where_its_field_reads_the_rest_value(skin):
    """Counts computed from known places give those places back: on its chip's axis, a hair
    off it (where the closed form of B_rho cancels), and well off it."""
    effect, _, _ = skin()
    lateral = np.array([[0.0, 0.0], [1e-12, 0.0], [0.0, -3e-9], [3e-4, -2e-4], [-6e-4, 1e-4]])
    height = np.array([0.0023, 0.0035, 0.0041, 0.0027, 0.0039])
    rows = np.arange(len(height))       # five of the hand's magnets, each with its remanence
    field = effect.field(np.column_stack([lateral, height]), rows)
    rest = CHIP_ZERO + field / np.array([effect.sensitivity_xy, effect.sensitivity_xy,
                                         effect.sensitivity_z])
    placed_lateral, placed_height = effect.placement(rest, rows)
    np.testing.assert_allclose(placed_height, height, rtol=1e-9)
    np.testing.assert_allclose(placed_lateral, lateral, rtol=0, atol=1e-9 * height.max())


def test_a_readout_offset_shifts_x_and_y_as_imanlabs_modules_rest_and_clips_at_16_bits(run_scene):
    """imanlab's public 4x4 modules rest near X 48,800 and Y 16,400: the same hand with that
    readout offset reads the same counts shifted on X and Y (Z untouched); readings pushed past
    either end of the 16-bit range clip there instead of wrapping. The magnets do not move."""
    name = 'calibration_index_tip_edge'
    plain = stack(run_scene(name, effects=MAGNETIC, steps=400, seed=2), 'taxel_counts')
    for offset in ((16032.0, -16368.0), (32000.0, -32000.0)):
        shifted = stack(run_scene(name, effects={'magnetic_skin': {'readout_offset_xy': offset}},
                                  steps=400, seed=2), 'taxel_counts')
        expected = plain.astype(float) + np.array([*offset, 0.0])
        np.testing.assert_array_equal(shifted, np.clip(expected, 0, 65535))
        if offset[0] == 16032.0:
            assert 48300 < np.median(shifted[..., 0]) < 49300
            assert 15900 < np.median(shifted[..., 1]) < 16900
        else:
            assert (shifted[..., 0] == 65535).any() and (shifted[..., 1] == 0).any()


def test_a_placement_that_does_not_converge_is_refused_with_the_reason(skin, monkeypatch):
    """The error skin_sensitivity reports as an infeasible variant, not a crash."""
    effect, _, _ = skin()
    monkeypatch.setattr(magnetic_skin, 'PLACEMENT_ITERATIONS', 1)
    with pytest.raises(SkinPlacementError, match='no magnet place reads the rest values within 1'):
        effect.placement(effect.rest_counts)


def test_a_press_raises_z_most_under_it_and_a_sharp_plate_concentrates(skin):
    effect, arr, c = skin()
    normal = arr.rotations[c, :, 2]
    spread = {}
    for plate in (Plate('button', 'sphere', 0.002), Plate('flat', 'plane', 0.0)):
        contact = Contact(1.0 * normal, arr.positions[c], normal, arr.rotations[c, :, 0], True)
        change = effect.counts_at(effect.displacement(contact, plate), arr.flat_indices)
        change -= effect.rest_counts[arr.flat_indices]
        assert change[:, 2].sum() > 0
        if plate.name == 'button':     # the flat plate presses all alike
            assert np.argmax(change[:, 2]) == c
        spread[plate.name] = change[c, 2] / change[:, 2].sum()
    assert spread['button'] > 3 * spread['flat']
    released = Contact(np.zeros(3), arr.positions[c], normal, arr.rotations[c, :, 0], False)
    np.testing.assert_array_equal(effect.displacement(released, plate), 0.0)


def test_a_magnet_pressed_past_its_chip_stays_above_it(skin):
    """A displacement the linear solution would take beyond the chip leaves the magnet at the
    neo-Hookean column's length; a small one reads as the linear solution does."""
    effect, arr, _ = skin()
    rows = arr.flat_indices
    height = effect.height[rows]
    ratios = np.array([-1e-6, -1.5])
    half = 0.5 * effect.magnet_thickness
    for ratio in ratios:
        displacement = np.zeros((len(rows), 3))
        displacement[:, 2] = ratio * (height - half)      # the column under the magnet
        stretch = float(phys.neo_hookean_stretch(np.array(ratio)))
        position = np.column_stack([effect.lateral[rows], stretch * (height - half) + half])
        expected = effect.field(position, rows) / np.array(
            [effect.sensitivity_xy, effect.sensitivity_xy, effect.sensitivity_z])
        unclipped = np.abs(expected).max(axis=1) < CHIP_RANGE
        assert unclipped.sum() > len(rows) // 4
        np.testing.assert_allclose(effect.counts_at(displacement, rows)[unclipped],
                                   CHIP_ZERO + expected[unclipped], rtol=1e-12)


def test_the_magnetic_skin_refuses_what_it_supersedes():
    with pytest.raises(ValueError, match="'magnetic_skin' models what \\['deformation'\\]"):
        Pipeline.from_scene({'magnetic_skin': {}, 'deformation': {}})


def test_magnetic_skin_alone_is_deterministic_and_changes_only_counts(run_scene):
    name = 'calibration_index_tip_convex'
    a = run_scene(name, effects=MAGNETIC, steps=400, seed=2)
    b = run_scene(name, effects=MAGNETIC, steps=400, seed=2)
    plain = run_scene(name, effects={}, steps=400, seed=2)
    assert np.array_equal(stack(a, 'taxel_counts'), stack(b, 'taxel_counts'))
    assert not np.array_equal(stack(a, 'taxel_counts'), stack(plain, 'taxel_counts'))
    for field in ('temperatures', 'ft_wrench', 'true_force'):
        assert np.array_equal(stack(a, field), stack(plain, field)), field


def test_a_scene_with_the_magnetic_skin_and_chip_effects_runs(hand):
    scene = load_scene('calibration_index_tip_flat')
    effects = {'magnetic_skin': {}, **{k: v for k, v in scene.effects.items()
                                       if k not in MagneticSkin.supersedes}}
    sim = make_simulator(dataclasses.replace(scene, effects=effects), hand, seed=0)
    counts = np.array([sim.step().taxel_counts for _ in range(300)]).astype(float)
    assert counts.min() >= 0 and counts.max() <= 65535


def test_the_magnetic_skin_reads_as_before_it_was_made_faster(tmp_path):
    """Every plate on a curved and a flat array, and the closed-loop press, against the
    readings the code before the speed-up wrote (test/sim/skin_reference.py, from 9d82c4b):
    within one count, the readout's rounding of float counts that differ in their last bits
    (sums taken in another order, the column's stretch in closed form instead of by Newton), and
    in at most 1 % of the readings (at 2026-11-28's speed-up: none)."""
    from skin_reference import REFERENCE, readings
    reference = np.load(REFERENCE)
    now = readings(tmp_path)
    assert sorted(now) == sorted(reference.files)
    for case in reference.files:
        assert now[case].shape == reference[case].shape, case
        off = np.abs(now[case].astype(np.int64) - reference[case].astype(np.int64))
        assert off.max() <= 1, f'{case}: {off.max()} counts from the reference'
        # A Young's modulus 0.1 % off moves 4-21 % of a case's readings, by up to 5 counts.
        assert np.mean(off > 0) <= 0.01, f'{case}: {np.mean(off > 0):.1%} of readings moved'


def test_each_module_and_magnet_is_its_own_and_the_same_in_every_session(skin, hand):
    """Arrays are cast apart (layer thickness, elastomer modulus) and magnets differ within
    their grade; a hand (its sensor seed) keeps them; the pressed array's layer is its own."""
    effect, arr, _ = skin()
    modules = len(hand.arrays)
    assert len(np.unique(effect.module_layer)) == modules
    assert len(np.unique(effect.module_modulus)) == modules
    remanence = effect.remanence * effect._remanence_scale
    assert 1.32 <= remanence.min() and remanence.max() <= 1.37
    other, _, _ = skin('middle_middle')
    np.testing.assert_array_equal(other.module_layer, effect.module_layer)
    np.testing.assert_array_equal(other.height, effect.height)
    index = [a.name for a in hand.arrays].index(arr.name)
    np.testing.assert_allclose(effect._layer.depths,
                               effect.module_layer[index] - effect.height[arr.flat_indices])
    assert effect.contact_modulus == pytest.approx(
        effect.module_modulus[index] / (1.0 - effect.poisson ** 2))
    alike, _, _ = skin(module_layer_spread=0.0, module_modulus_spread=0.0, remanence_spread=0.0)
    assert np.all(alike.module_layer == alike.layer_thickness)
    np.testing.assert_allclose(alike.rest_counts, effect.rest_counts, rtol=1e-12)   # as drawn


def test_a_left_hand_of_the_same_sensor_seed_is_another_hand():
    """A lab's two hands have their own modules: the left hand's draws carry its side, and the
    right hand's are those of its sensor seed as before."""
    from tacforce_ros.hand.description import hand_config, load_hand
    from tacforce_ros.sim.effects import HAND_STREAM
    import zlib
    rest = {}
    for side in ('right', 'left'):
        hand = load_hand(hand_config(side))
        array_of = np.empty(hand.n_taxels, np.int64)
        for index, each in enumerate(hand.arrays):
            array_of[each.flat_indices] = index
        arr = hand.array('palm_center')
        ctx = SimpleNamespace(hand=hand, n_taxels=hand.n_taxels, array=arr,
                              rows=arr.flat_indices, array_of_taxel=array_of, dt=0.01)
        effect = MagneticSkin()
        Pipeline([effect]).reset(0, ctx, sensor_seed=7)
        rest[side] = effect.rest_counts.copy()
        if side == 'right':
            again = MagneticSkin()
            again.draw_hand(np.random.default_rng(
                [7, zlib.crc32(again.name.encode()), HAND_STREAM]), ctx)
            np.testing.assert_array_equal(again.rest_counts, rest['right'])
    assert not np.allclose(rest['left'], rest['right'])
