"""What every navigation filter is built from, loaded from the user's files: the nominal vehicle, the design
data set (→ the FADS port model and the stability derivatives), and the port aero models (DEIM, DEIM+NN).
The benchmark, the replay and the companion service load them the same way."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from vdm_aero.errors import ModelError
from vdm_aero.model import AeroModel, read_model_yaml
from vdm_aero.nav.design_fit import DesignFlightData, PortPressureModel, StabilityDerivatives
from vdm_aero.nav.port_speed_calibration import PortSpeedCalibration
from vdm_aero.nav.ports_frontend import PortFrontEnd
from vdm_aero.vehicle import VehicleDescription, load_vehicle

__all__ = ["NavModels"]


@dataclass(frozen=True)
class NavModels:
    vehicle: VehicleDescription
    derivatives: StabilityDerivatives
    pressure_model: PortPressureModel
    models: dict[str, AeroModel]  # "deim", and "deim-nn" when given
    # the ports' airspeed table from the calibrated model's flight (model.yaml calibration.port_speed), if any
    port_speed: PortSpeedCalibration | None = None

    @property
    def port_names(self) -> tuple[str, ...]:
        return self.models["deim"].port_names

    def front_end(self, *, range_pa: float, noise_pa: float) -> PortFrontEnd:
        """A port front end on these models (one per run: it keeps the ports' health and the warm start)."""
        return PortFrontEnd(self.pressure_model, dict(self.models), range_pa=range_pa, noise_pa=noise_pa,
                            speed_calibration=self.port_speed)  # fmt: skip

    @classmethod
    def load(cls, design_data: Path, deim_dir: Path, nn_dir: Path | None, vehicle: str | Path = "uav-2m"
             ) -> NavModels:  # fmt: skip
        """Load the aero models and fit the design-data models (seconds; errors name the file)."""
        deim = AeroModel.load(deim_dir)
        models = {"deim": deim}
        if nn_dir is not None:
            nn = AeroModel.load(nn_dir)
            if nn.port_names != deim.port_names:
                raise ModelError(f"{nn_dir}: ports {nn.port_names} differ from {deim_dir}'s {deim.port_names}")
            models["deim-nn"] = nn
        data = DesignFlightData.load(design_data, deim.port_names)
        return cls(load_vehicle(vehicle), StabilityDerivatives.fit(data), PortPressureModel.fit(data), models,
                   _port_speed(nn_dir))  # fmt: skip

    @classmethod
    def from_model(cls, design_data: Path, model_dir: Path, vehicle: str | Path = "uav-2m") -> NavModels:
        """One model directory: DEIM alone, or DEIM with its correction net (then both modes, "deim" being the
        same model without the net)."""
        m = AeroModel.load(model_dir)
        models = {"deim": m.with_correction(None)} | ({"deim-nn": m} if m.has_correction else {})
        data = DesignFlightData.load(design_data, m.port_names)
        return cls(load_vehicle(vehicle), StabilityDerivatives.fit(data), PortPressureModel.fit(data), models,
                   _port_speed(model_dir))  # fmt: skip


def _port_speed(model_dir: Path | None) -> PortSpeedCalibration | None:
    """The airspeed table a flight calibration wrote into ``model_dir``'s model.yaml (models calibrated before
    2026-11-30, and those trained on the design data alone, have none)."""
    if model_dir is None:
        return None
    cal = read_model_yaml(model_dir).get("calibration")
    table = cal.get("port_speed") if isinstance(cal, dict) else None
    return None if table is None else PortSpeedCalibration.from_dict(table, str(model_dir / "model.yaml"))
