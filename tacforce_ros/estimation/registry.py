"""Model kinds by name (the `kind` stored in model files and shown in ForceEstimate)."""
from __future__ import annotations

from tacforce_ros.estimation.base import ForceModel
from tacforce_ros.estimation.m1_rotation_linear import M1Linear
from tacforce_ros.estimation.m2_rotation_quadratic import M2Quadratic
from tacforce_ros.estimation.m3_lambda import DEFAULT_GRID, PAPER_LAMBDA, M3Lambda
from tacforce_ros.estimation.m3_linear import M3Linear
from tacforce_ros.estimation.m4_mlp import MLPModel
from tacforce_ros.estimation.m5_cnn import CNNModel

MODEL_KINDS: dict[str, type[ForceModel]] = {
    cls.kind: cls for cls in (M1Linear, M2Quadratic, M3Linear, M3Lambda, MLPModel, CNNModel)}
# Trained by torch from a seeded random start: they take a seed and a training device.
TORCH_KINDS = (MLPModel.kind, CNNModel.kind)


def model_class(kind: str) -> type[ForceModel]:
    try:
        return MODEL_KINDS[kind]
    except KeyError:
        raise ValueError(f'unknown model kind {kind!r}; known: {sorted(MODEL_KINDS)}') from None

PAPER_LABELS = ('M1', 'M2', 'M3', 'M3-lambda', 'M3-lambda-cv', 'M4', 'M5')


def paper_configurations(seed: int, epochs: int) -> dict[str, tuple[str, dict]]:
    """The paper's models as compared in Table I (and M3-lambda with its lambda chosen by
    cross-validation): label -> (kind, hyper-parameters)."""
    torch_hyper = {'seed': seed, 'epochs': epochs}
    return {
        'M1': ('M1', {}), 'M2': ('M2', {}), 'M3': ('M3', {}),
        'M3-lambda': ('M3-lambda', {'lam': PAPER_LAMBDA, 'lambda_grid': None}),
        'M3-lambda-cv': ('M3-lambda', {'lam': PAPER_LAMBDA, 'lambda_grid': list(DEFAULT_GRID)}),
        'M4': ('M4', dict(torch_hyper)), 'M5': ('M5', dict(torch_hyper)),
    }
