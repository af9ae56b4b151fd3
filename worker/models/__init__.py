"""BRDF models, one module each (see base.py). Importing this package registers the built-in
models; ``models()`` lists every registered one, ``parse_material`` validates any of them."""
from .base import (BRDFModel, Color, Geometry, Material, PackedBRDF, Vec3, describe, material_adapter,  # noqa: F401
                   model_class, models, parse_material, register, unregister)
from .lambert import Lambert  # noqa: F401  (registration order: the studio's menu order)
from .ggx import GGX  # noqa: F401
from .blinn_phong import BlinnPhong  # noqa: F401
from .curve import Curve  # noqa: F401
from .lobes import Lobes  # noqa: F401
from .srbf import SRBF  # noqa: F401
from .ashikhmin_shirley import AshikhminShirley  # noqa: F401
from .regions import Region, Regions, has_regions, layer_weights  # noqa: F401  (composes the others: last)
