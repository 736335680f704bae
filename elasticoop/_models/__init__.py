"""The two models of the appendix: `ImmobileModel` (Appendix A) and `MobileModel`
(Appendix B), as stated in `docs/model.md` (sections 2 and 3)."""

from .base import AbstractElasticModel as AbstractElasticModel
from .immobile import ImmobileModel as ImmobileModel
from .linearize import linearize_mobile as linearize_mobile
from .mobile import (
    Connection as Connection,
    MobileModel as MobileModel,
    connection_dissipation as connection_dissipation,
    connection_potential as connection_potential,
    deflection as deflection,
)
