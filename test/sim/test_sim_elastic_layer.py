"""The bonded elastic layer against cases computed by hand: a uniform load on the whole surface,
the half space near a load in a thick layer, isotropy, and what it refuses."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tacforce_ros.sim.elastic_layer import BondedLayer

E, H = 87e3, 0.005               # Pa, m: the magnetic skin's elastomer and layer
DEPTHS = np.array([0.001, 0.0025, 0.004])


def shear_modulus(poisson: float) -> float:
    return E / (2.0 * (1.0 + poisson))


@pytest.fixture(scope='module', params=[0.3, 0.49])
def layer(request):
    """(layer, Poisson's ratio): a compressible and a nearly incompressible elastomer."""
    return BondedLayer(H, shear_modulus(request.param), request.param, DEPTHS), request.param


def uniform_load(layer, traction: np.ndarray) -> np.ndarray:
    """(n, 3) displacement at the layer's depths under `traction` (Pa) on the whole surface,
    as point loads on a 0.2 mm grid over a square reaching past the table's range."""
    step = 0.0002
    grid = np.arange(-60e-3, 60e-3 + 0.5 * step, step)
    x, y = np.meshgrid(grid, grid)
    lateral = np.broadcast_to(np.stack([x.ravel(), y.ravel()], axis=-1),
                              (layer.depths.size, x.size, 2))
    return layer.displacement(lateral, traction * step * step).sum(axis=1)


def test_a_uniform_pressure_compresses_the_layer_as_a_confined_column(layer):
    """No lateral strain anywhere: u_z(z) = p (h - z) / M with M = 2 G (1 - nu) / (1 - 2 nu);
    an incompressible layer would not move at all."""
    layer, nu = layer
    p = 1000.0
    confined = 2.0 * shear_modulus(nu) * (1.0 - nu) / (1.0 - 2.0 * nu)
    moved = uniform_load(layer, np.array([0.0, 0.0, p]))
    np.testing.assert_allclose(moved[:, 2], p * (H - DEPTHS) / confined, rtol=0.02)
    np.testing.assert_allclose(moved[:, :2], 0.0, atol=1e-3 * np.abs(moved[:, 2]).max())


def test_a_uniform_shear_shears_the_layer_in_proportion_to_its_height(layer):
    layer, nu = layer
    tau = 1000.0
    moved = uniform_load(layer, np.array([tau, 0.0, 0.0]))
    np.testing.assert_allclose(moved[:, 0], tau * (H - DEPTHS) / shear_modulus(nu), rtol=0.01)
    np.testing.assert_allclose(moved[:, 1:], 0.0, atol=1e-3 * moved[:, 0].max())


def test_near_the_load_a_thick_layer_is_a_half_space():
    """Boussinesq and Cerruti (Johnson 1985, eqs. 3.19, 3.86-3.88): at a depth of a twentieth
    of the layer the parts of the response that turn with the load match theirs; the parts that
    do not are offset by how far the whole neighbourhood sinks, so their differences do."""
    G, nu, z = 30e3, 0.45, 0.002
    layer = BondedLayer(20 * z, G, nu, np.array([z]))
    r = np.array([0.0005, 0.001, 0.002, 0.004])
    rho, c, scale = np.sqrt(r * r + z * z), 1.0 - 2.0 * nu, 1.0 / (4.0 * np.pi * G)
    half_space = {
        'nr': scale * (r * z / rho ** 3 - c * r / (rho * (rho + z))),
        'c': scale * (r * z / rho ** 3 + c * r / (rho * (rho + z))),
        'b': -scale * 0.5 * r * r * (1.0 / rho ** 3 - c / (rho * (rho + z) ** 2)),
        'nz': scale * (z * z / rho ** 3 + 2.0 * (1.0 - nu) / rho),
        'a': scale * (1.0 / rho + c / (rho + z)
                      + 0.5 * r * r * (1.0 / rho ** 3 - c / (rho * (rho + z) ** 2)))}
    at = {name: np.interp(r, layer.radii, table[0]) for name, table in layer.tables.items()}
    for name in ('nr', 'c', 'b'):
        np.testing.assert_allclose(at[name], half_space[name], rtol=0.03, err_msg=name)
    for name in ('nz', 'a'):
        np.testing.assert_allclose(at[name] - at[name][-1],
                                   half_space[name] - half_space[name][-1], rtol=0.01,
                                   err_msg=name)


def test_the_board_confines_the_response_to_a_few_thicknesses(layer):
    """A half space's response falls as 1 / r; the bonded layer's dies out within a few
    thicknesses of the load."""
    layer, _ = layer

    def size(r):
        lateral = np.broadcast_to([r, 0.0], (layer.depths.size, 1, 2))
        return np.abs(layer.displacement(lateral, np.eye(3)[None])).max()   # each axis
    assert size(4 * H) < 0.02 * size(0.0)


@settings(max_examples=40, deadline=None)
@given(angle=st.floats(-np.pi, np.pi), x=st.floats(-0.02, 0.02), y=st.floats(-0.02, 0.02),
       force=st.tuples(*[st.floats(-1.0, 1.0)] * 3))
def test_the_response_turns_with_the_load(isotropic, angle, x, y, force):
    cos, sin = np.cos(angle), np.sin(angle)
    turn = np.array([[cos, -sin, 0.0], [sin, cos, 0.0], [0.0, 0.0, 1.0]])
    force = np.array(force)
    lateral = np.broadcast_to([x, y], (DEPTHS.size, 2))
    moved = isotropic.displacement(lateral, force)
    turned = isotropic.displacement(lateral @ turn[:2, :2].T, turn @ force)
    # The tables depend on the distance only; turning changes it by rounding.
    np.testing.assert_allclose(turned, moved @ turn.T, rtol=0.0,
                               atol=1e-9 * np.abs(moved).max() + 1e-18)


@pytest.fixture(scope='module')
def isotropic():
    return BondedLayer(H, shear_modulus(0.49), 0.49, DEPTHS)


@pytest.mark.parametrize('depths, poisson, words', [
    ([0.0, 0.002], 0.49, ['inside', 'layer']),
    ([0.002, H], 0.49, ['inside', 'layer']),
    ([0.002], 0.5, ['Poisson', '0.5']),
])
def test_points_outside_the_layer_or_an_incompressible_solid_are_refused(depths, poisson, words):
    with pytest.raises(ValueError) as error:
        BondedLayer(H, shear_modulus(0.49), poisson, np.array(depths))
    assert all(word in str(error.value) for word in words)


def test_a_load_for_other_field_points_is_refused(isotropic):
    with pytest.raises(ValueError, match='2 field points given, 3 tabulated'):
        isotropic.displacement(np.zeros((2, 2)), np.array([0.0, 0.0, 1.0]))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), reach=st.floats(1e-4, 0.08))
def test_the_unit_response_is_the_displacement_of_unit_loads_summed(isotropic, seed, reach):
    """unit_response_at, from the points' distances and directions, against `displacement`
    of a unit load along each axis, summed over the points with their shares; points beyond the
    table's reach (60 mm) included."""
    rng = np.random.default_rng(seed)
    lateral = rng.uniform(-reach, reach, (DEPTHS.size, 9, 2))
    shares = rng.uniform(0.0, 1.0, 9)
    expected = np.stack([np.einsum('k,nkd->nd', shares, isotropic.displacement(lateral, unit))
                         for unit in np.eye(3)], axis=1)
    scale = np.abs(expected).max()
    distance = np.hypot(lateral[..., 0], lateral[..., 1])
    got = isotropic.unit_response_at(distance, -lateral[..., 0] / distance,
                                     -lateral[..., 1] / distance, shares)
    np.testing.assert_allclose(got, expected, rtol=0.0, atol=1e-12 * scale)
