"""Vehicle models (FlightGear AC3D -> GLB), people (anny bodies -> GLB) and the lookup of vehicle and detector
data."""

from garage_exp.assets.locate import models_dir, vehicles_dir
from garage_exp.assets.people import PeopleLibrary, PersonModel
from garage_exp.assets.vehicles import VehicleLibrary, VehicleModel, kind_of

__all__ = ["PeopleLibrary", "PersonModel", "VehicleLibrary", "VehicleModel", "kind_of", "models_dir", "vehicles_dir"]
