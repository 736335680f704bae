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
