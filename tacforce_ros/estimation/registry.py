"""Model kinds by name (the `kind` stored in model files and shown in ForceEstimate)."""
from __future__ import annotations

from tacforce_ros.estimation.base import ForceModel
from tacforce_ros.estimation.m1_rotation_linear import M1Linear
from tacforce_ros.estimation.m2_rotation_quadratic import M2Quadratic
from tacforce_ros.estimation.m3_lambda import M3Lambda
from tacforce_ros.estimation.m3_linear import M3Linear
from tacforce_ros.estimation.m4_mlp import MLPModel
from tacforce_ros.estimation.m5_cnn import CNNModel

MODEL_KINDS: dict[str, type[ForceModel]] = {
    cls.kind: cls for cls in (M1Linear, M2Quadratic, M3Linear, M3Lambda, MLPModel, CNNModel)}


def model_class(kind: str) -> type[ForceModel]:
    try:
        return MODEL_KINDS[kind]
    except KeyError:
        raise ValueError(f'unknown model kind {kind!r}; known: {sorted(MODEL_KINDS)}') from None
