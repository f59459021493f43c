"""Devices describe their field of view: a sensor type declares it, the simulated cell
measures with it and the planner puts the sphere at its standoff; [simulation.fov]
overrides fields of it; the core holds no sensor's numbers as defaults."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import BaseModel, ConfigDict, ValidationError

from spherecal.config import load_config
from spherecal.devices.contract import SensorFieldOfView, SensorType
from spherecal.core.errors import ConfigError
from spherecal.motion.planning import SweepPlan, plan_stations, sphere_centres_in_sensor, with_standoff
from spherecal.plugins import hookimpl
from spherecal.plugins.host import PluginHost
from spherecal.app import plugin_host
from spherecal.app.cell import configured_for_sensor, make_cell, sensor_field_of_view
from spherecal.sensors.nxsensor_i.plugin import FIELD_OF_VIEW as NXSENSOR_FOV

#: A third-party profiler's field of view, unlike the nxSensor-I's.
SMALL = SensorFieldOfView(z_near_mm=15.0, z_far_mm=-15.0, width_near_mm=18.0, width_far_mm=26.0)


class _Config(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


def host_with_profiler(fov: SensorFieldOfView | None) -> PluginHost:
    """The installed plugins plus a sensor type 'acme_profiler' declaring ``fov``."""

    class Plugin:
        @staticmethod
        @hookimpl
        def spherecal_register_devices(registry):
            registry.add_sensor(SensorType(name="acme_profiler", config_model=_Config, factory=lambda c, ctx: None,
                                           field_of_view=fov))

    return PluginHost(plugins=[("acme", Plugin)])


def config_with(sim_config, sensor: str = "acme_profiler", fov_toml: str = ""):
    path = sim_config(**{r'^type = "nxsensor_i"$': f'type = "{sensor}"',
                         r"^\[simulation\]$": "[simulation]" + (f"\nfov = {{ {fov_toml} }}" if fov_toml else "")})
    return load_config(path)


def test_the_core_defaults_to_no_sensors_numbers():
    from spherecal.config import ScanConfig, SimulationConfig

    assert SimulationConfig().fov is None
    assert SweepPlan().standoff_z_mm is None
    assert ScanConfig.model_fields["standoff_z_mm"].default is None
    with pytest.raises(ValidationError):  # no default range: a sensor must say
        SensorFieldOfView()


def test_the_nxsensor_declares_its_own_and_a_configured_cell_uses_it(sim_config):
    host = PluginHost()
    assert host.registry.sensor_type("nxsensor_i").field_of_view == NXSENSOR_FOV
    assert (NXSENSOR_FOV.z_near_mm, NXSENSOR_FOV.z_far_mm, NXSENSOR_FOV.width_near_mm,
            NXSENSOR_FOV.width_far_mm) == (40.0, -60.0, 28.0, 48.0)  # docs/sensor-nxsensor-i.md
    loaded = load_config(sim_config())
    fov = sensor_field_of_view(loaded.config, host)
    assert fov == NXSENSOR_FOV
    assert make_cell(loaded.config, field_of_view=fov).fov == NXSENSOR_FOV


def test_a_third_party_sensor_is_simulated_and_planned_with_its_declared_field_of_view(sim_config):
    host = host_with_profiler(SMALL)
    loaded, fov = configured_for_sensor(config_with(sim_config), host)
    assert fov == SMALL
    # the planner puts the sphere centre in the sensor's own range, not at the nxSensor's -20 mm: SMALL declares
    # no standoff, and the 19.1 mm sphere is too large for its 30 mm range with the stations' offsets, so the
    # middle of what they leave (sphere_standoff_z_mm): its top 11.35 mm, inside the near end (15 mm)
    assert loaded.config.acquisition.sweep.standoff_z_mm == pytest.approx(-7.75)
    cell = make_cell(loaded.config, field_of_view=fov)
    assert cell.fov == SMALL
    # every point the simulated sensor measures lies in the declared range and line width
    from spherecal.motion.acquisition import plan_targets

    seen = 0
    cfg = loaded.config
    for target in plan_targets(cfg.acquisition, cfg.mounting, cfg.nominal_transform, cfg.sphere)[:40]:
        cell.move_flange_to(target.pose)
        pts = cell.ideal_profile(target.pose)
        seen += len(pts)
        if len(pts):
            assert pts[:, 1].max() <= SMALL.z_near_mm + 1e-9 and pts[:, 1].min() >= SMALL.z_far_mm - 1e-9
            half = SMALL.width_near_mm / 2 + (SMALL.z_near_mm - pts[:, 1]) * np.tan(SMALL.half_angle_rad)
            assert np.all(np.abs(pts[:, 0]) <= half + 1e-9)
    assert seen > 0


def test_simulation_fov_overrides_fields_of_the_declared_one(sim_config):
    loaded = config_with(sim_config, "nxsensor_i", "n_columns = 160, standoff_z_mm = -30.0")
    fov = sensor_field_of_view(loaded.config, PluginHost())
    assert fov == NXSENSOR_FOV.model_copy(update={"n_columns": 160, "standoff_z_mm": -30.0})
    loaded, _ = configured_for_sensor(loaded, PluginHost())
    assert loaded.config.acquisition.sweep.standoff_z_mm == -30.0


def test_a_sensor_without_a_field_of_view_must_be_given_one_in_the_toml(sim_config, monkeypatch):
    host = host_with_profiler(None)
    monkeypatch.setattr(plugin_host, "make_host", lambda enable=None: host)  # the run's plugins
    loaded = config_with(sim_config)
    assert sensor_field_of_view(loaded.config, host) is None
    with pytest.raises(ConfigError, match=r"simulation.fov: sensor type 'acme_profiler' declares no field of view; "
                                          r"give z_near_mm, z_far_mm, width_near_mm and width_far_mm"):
        make_cell(loaded.config, field_of_view=sensor_field_of_view(loaded.config, host))
    with pytest.raises(ConfigError, match=r"simulation.fov \(sensor type 'acme_profiler' declares no field of "
                                          r"view\): z_far_mm: Field required"):
        sensor_field_of_view(config_with(sim_config, fov_toml="z_near_mm = 15.0, width_near_mm = 18.0, "
                                         "width_far_mm = 26.0").config, host)
    given = config_with(sim_config, fov_toml="z_near_mm = 15.0, z_far_mm = -15.0, width_near_mm = 18.0, "
                        "width_far_mm = 26.0")
    assert sensor_field_of_view(given.config, host) == SMALL
    # and the planner, told nothing, says which setting it needs
    with pytest.raises(ConfigError, match=r"acquisition.sweep.standoff_z_mm: not set, and the sensor type declares "
                                          "no field of view"):
        with_standoff(SweepPlan(), None)


def test_a_bad_override_names_simulation_fov(sim_config):
    loaded = config_with(sim_config, "nxsensor_i", "z_far_mm = 50.0")
    with pytest.raises(ConfigError, match=r"simulation.fov \(over sensor type 'nxsensor_i'.s field of view\): "
                                          r".*z_far_mm \(50.0\) must be below z_near_mm \(40.0\)"):
        sensor_field_of_view(loaded.config, PluginHost())


@pytest.mark.parametrize("fields, message", [
    (dict(z_near_mm=-60.0, z_far_mm=40.0, width_near_mm=28.0, width_far_mm=48.0), "must be below z_near_mm"),
    (dict(z_near_mm=40.0, z_far_mm=-60.0, width_near_mm=48.0, width_far_mm=28.0), "must exceed width_near_mm"),
    (dict(z_near_mm=40.0, z_far_mm=-60.0, width_near_mm=28.0, width_far_mm=48.0, standoff_z_mm=50.0),
     r"standoff_z_mm \(50.0\) must lie in the measuring range \[-60.0, 40.0\]"),
])
def test_a_field_of_view_that_is_not_a_fan_is_refused(fields, message):
    with pytest.raises(ValidationError, match=message):
        SensorFieldOfView(**fields)


def test_the_fan_matches_the_declared_widths_and_the_standoff_moves_the_sweep():
    # the fan's apex and angle reproduce the line width at both ends
    for fov in (NXSENSOR_FOV, SMALL):
        for z, width in ((fov.z_near_mm, fov.width_near_mm), (fov.z_far_mm, fov.width_far_mm)):
            assert 2 * (fov.apex_z_mm - z) * np.tan(fov.half_angle_rad) == pytest.approx(width, rel=1e-12)
    assert NXSENSOR_FOV.apex_z_mm == pytest.approx(180.0)
    plan = SweepPlan(profiles_per_station=8)
    for fov, standoff in ((NXSENSOR_FOV, -20.0), (SMALL, 0.0)):
        centres = sphere_centres_in_sensor(with_standoff(plan, fov), 19.1)
        assert np.mean(centres[:, 2]) == pytest.approx(standoff, abs=1e-9)  # the wander's cosine sums to zero
    # a standoff given in the plan wins over the sensor's
    assert with_standoff(SweepPlan(standoff_z_mm=-7.0), SMALL).standoff_z_mm == -7.0
    a = plan_stations("eye_in_hand", _identity(), [0, 0, 0], 19.1, plan, field_of_view=NXSENSOR_FOV)
    b = plan_stations("eye_in_hand", _identity(), [0, 0, 0], 19.1, plan.model_copy(update={
        "standoff_z_mm": -20.0, "lateral_amplitude_mm": 4.0,
        "station_offsets_mm": [(0.0, 0.0), (10.0, -25.0), (-10.0, 18.0), (0.0, -30.0)]}))
    assert all(np.allclose(p.translation, q.translation) for (_, s), (_, t) in zip(a, b) for p, q in zip(s, t))


def _identity():
    from spherecal.core.models import Pose

    return Pose.identity()


def test_a_cell_built_without_a_sensor_must_be_given_a_field_of_view():
    import spherecal.sim as sim
    from spherecal.core.models import Pose
    from spherecal.sim import SimulatedCell, standard_cell

    assert not hasattr(sim, "REFERENCE_FIELD_OF_VIEW")  # the simulator holds no sensor's numbers
    with pytest.raises(TypeError, match=r"standard_cell: fov is required: the field of view of the sensor"):
        standard_cell("eye_in_hand", seed=0)
    with pytest.raises(TypeError, match=r"SimulatedCell: fov is required"):
        SimulatedCell("eye_in_hand", Pose.identity(), (0.0, 0.0, 0.0), 10.0, None)
    with pytest.raises(TypeError, match=r"standard_cell: fov must be a spherecal.devices.contract.SensorFieldOfView, got dict"):
        standard_cell("eye_in_hand", fov={"z_near_mm": 40.0})
    assert standard_cell("eye_in_hand", fov=SMALL).fov is SMALL


#: A sensor with a 25 mm measuring range (standoff: the middle) and one with 400 mm.
RANGE_25 = SensorFieldOfView(z_near_mm=12.5, z_far_mm=-12.5, width_near_mm=10.0, width_far_mm=14.0)
RANGE_400 = SensorFieldOfView(z_near_mm=150.0, z_far_mm=-250.0, width_near_mm=120.0, width_far_mm=280.0,
                              standoff_z_mm=-80.0)
#: The default plan's offsets and wander as they were, in mm: sized for a 100 mm range.
FIXED_MM = {"station_offsets_mm": [(0.0, 0.0), (10.0, -25.0), (-10.0, 18.0), (0.0, -30.0)], "lateral_amplitude_mm": 4.0}


def _sections_outside(cell, plan) -> list[str]:
    """The planned shots whose sphere section is not inside the cell's field of view: its
    visible half (from the centre's z up to the top of the circle the laser plane cuts)
    out of the measuring range, or its centre off the line."""
    fov, r = cell.fov, cell.sphere_radius_mm
    out = []
    for label, poses in plan_stations(cell.mounting, cell.true_transform, cell.sphere_centre_mm, r, plan,
                                      field_of_view=fov):
        for k, pose in enumerate(poses):
            c = cell.sphere_centre_in_sensor(pose)
            rho = np.sqrt(r * r - c[0] ** 2)
            if not (fov.z_far_mm <= c[2] and c[2] + rho <= fov.z_near_mm
                    and abs(c[1]) <= fov.width_at_mm(c[2]) / 2 and len(cell.ideal_profile(pose)) >= 20):
                out.append(f"{label}/{k}: centre (y, z) = ({c[1]:.2f}, {c[2]:.2f}) mm, section radius {rho:.2f} mm")
    return out


def _centres_z_span_mm(cell, plan) -> float:
    """How far the planned sphere centres spread along the sensor's z, mm."""
    z = [cell.sphere_centre_in_sensor(pose)[2] for _, poses in plan_stations(
        cell.mounting, cell.true_transform, cell.sphere_centre_mm, cell.sphere_radius_mm, plan,
        field_of_view=cell.fov) for pose in poses]
    return float(np.ptp(z))


@pytest.mark.parametrize("mounting", ["eye_in_hand", "eye_to_hand"])
@pytest.mark.parametrize("fov, radius_mm", [(RANGE_25, 4.0), (NXSENSOR_FOV, 19.1), (RANGE_400, 50.0)],
                         ids=["25mm", "nxsensor", "400mm"])
def test_the_default_plan_fits_the_sensors_field_of_view(fov, radius_mm, mounting):
    from spherecal.sim import standard_cell

    cell = standard_cell(mounting, seed=0, fov=fov, sphere_radius_mm=radius_mm)
    assert _sections_outside(cell, SweepPlan()) == []
    fitted = with_standoff(SweepPlan(), fov)
    range_mm = fov.z_near_mm - fov.z_far_mm
    assert fitted.lateral_amplitude_mm == pytest.approx(0.04 * range_mm)
    assert [z for _, z in fitted.station_offsets_mm] == pytest.approx([0.0, -0.25 * range_mm, 0.18 * range_mm,
                                                                       -0.3 * range_mm])
    if fov is NXSENSOR_FOV:  # the nxSensor-I's plan is the one sized for it before, to the bit
        assert fitted.model_dump() == SweepPlan(standoff_z_mm=-20.0, **FIXED_MM).model_dump()
    elif fov is RANGE_25:  # the offsets sized for a 100 mm range do not fit a 25 mm one
        assert _sections_outside(cell, SweepPlan(**FIXED_MM)) != []
    else:  # and use a tenth of a 400 mm one, where the sized stations spread over half of it
        assert _centres_z_span_mm(cell, SweepPlan(**FIXED_MM)) < 0.15 * range_mm
        assert _centres_z_span_mm(cell, SweepPlan()) > 0.45 * range_mm
    # offsets and wander a plan gives are its own
    own = with_standoff(SweepPlan(station_offsets_mm=[(1.0, 2.0)], lateral_amplitude_mm=0.5), fov)
    assert own.station_offsets_mm == [(1.0, 2.0)] and own.lateral_amplitude_mm == 0.5


def test_a_plan_without_a_field_of_view_names_the_setting_it_lacks():
    with pytest.raises(ConfigError, match=r"acquisition.sweep.station_offsets_mm: not set, and the sensor type "
                                          r"declares no field of view"):
        with_standoff(SweepPlan(standoff_z_mm=-5.0), None)
    with pytest.raises(ConfigError, match=r"acquisition.sweep.lateral_amplitude_mm: not set"):
        with_standoff(SweepPlan(standoff_z_mm=-5.0, station_offsets_mm=[(0.0, 0.0)]), None)
    given = SweepPlan(standoff_z_mm=-5.0, station_offsets_mm=[(0.0, 0.0)], lateral_amplitude_mm=1.0)
    assert with_standoff(given, None) is given


#: The field of view of the profiler the simulate tests register (a 120 mm range).
WIDE = SensorFieldOfView(z_near_mm=60.0, z_far_mm=-60.0, width_near_mm=40.0, width_far_mm=70.0, n_columns=200)


def test_simulate_takes_the_sensor_type_by_name(tmp_path, monkeypatch, capsys):
    from spherecal.io import dataset as dataio
    from spherecal.cli import EXIT_OK, EXIT_USAGE, main

    monkeypatch.setattr(plugin_host, "make_host", lambda enable=None: host_with_profiler(WIDE))
    out = tmp_path / "acme.jsonl"
    assert main(["simulate", str(out), "--sensor", "acme_profiler", "--profiles", "4"]) == EXIT_OK
    ds = dataio.read_dataset(out)
    assert ds.provenance["fov"] == WIDE.model_dump()  # measured with the named sensor's field of view
    fitted = with_standoff(SweepPlan(profiles_per_station=4), WIDE, 19.1)  # the simulated cell's sphere
    # sized for the 19.1 mm sphere (WIDE declares no standoff): as near as the stations' offsets allow below
    # the near end (60 - 19.1 - 26 % of 120 mm), the line there 48.6 mm wide for a 38.2 mm sphere
    assert ds.provenance["plan"]["standoff_z_mm"] == pytest.approx(9.7)
    assert [tuple(o) for o in ds.provenance["plan"]["station_offsets_mm"]] == fitted.station_offsets_mm
    assert len(ds.observations) == 16  # every planned shot sees the sphere
    for obs in ds.observations:
        assert obs.profile.points_mm[:, 1].min() >= WIDE.z_far_mm and obs.profile.points_mm[:, 1].max() <= 60.0
    capsys.readouterr()
    # an unknown name: exit 2 naming the option and the installed types
    assert main(["simulate", str(tmp_path / "x.jsonl"), "--sensor", "acme_profilr"]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert "--sensor acme_profilr: unknown sensor type; installed sensor types: acme_profiler, nxsensor_i" in err
    # two sensor types declare a field of view: the user chooses
    assert main(["simulate", str(tmp_path / "y.jsonl")]) == EXIT_USAGE
    assert ("--sensor: give the sensor type to simulate (installed sensor types with a field of view: "
            "acme_profiler, nxsensor_i)") in capsys.readouterr().err
    assert not (tmp_path / "x.jsonl").exists() and not (tmp_path / "y.jsonl").exists()


@pytest.mark.parametrize("extra", [["--sensor", "nxsensor_i"], ["--mounting", "eye_to_hand"], ["--profiles", "6"],
                                   ["--point-noise-mm", "0.1"], ["--pose-noise-mm", "0"], ["--stray-fraction", "0.5"],
                                   ["--seed", "9"], ["--mounting", "eye_to_hand", "--seed", "9"]])
def test_simulate_options_that_clash_with_a_configuration_are_refused(tmp_path, sim_config, capsys, extra):
    """The configuration gives the sensor, mounting, plan, noise and (its [simulation]) seed:
    an option that would change them exits 2 naming it, never ignored."""
    from spherecal.cli import EXIT_USAGE, main

    out = tmp_path / "z.jsonl"
    assert main(["simulate", str(out), "--config", str(sim_config()), *extra]) == EXIT_USAGE
    err = capsys.readouterr().err
    assert extra[0] in err and not out.exists()
    assert ("[simulation] section, whose seed is used" in err) if extra == ["--seed", "9"] else \
        ("the configuration gives the sensor, the mounting, the plan and the noise" in err)


def test_simulate_without_a_name_uses_the_only_sensor_type_with_a_field_of_view(tmp_path, monkeypatch):
    from spherecal.io import dataset as dataio
    from spherecal.cli import EXIT_OK, main

    only = PluginHost(autoload=False)  # the built-ins: one sensor type, the nxSensor-I
    monkeypatch.setattr(plugin_host, "make_host", lambda enable=None: only)
    assert main(["simulate", str(tmp_path / "d.jsonl"), "--profiles", "4"]) == EXIT_OK
    assert dataio.read_dataset(tmp_path / "d.jsonl").provenance["fov"] == NXSENSOR_FOV.model_dump()


def test_the_default_validation_views_are_sized_to_the_field_of_view():
    from spherecal.config import FlatConfig, ValidationConfig
    from spherecal.motion.planning import site_offset_mm

    spheres = ValidationConfig().sphere_positions
    flat = FlatConfig(centre_mm=(0.0, 0.0, 0.0)).positions

    def offsets(sites, fov, standoff):
        return [site_offset_mm(s.offset_mm, s.offset_percent, fov, standoff, "validation") for s in sites]

    # the nxSensor-I's views are those sized for it before, to the bit
    assert offsets(spheres, NXSENSOR_FOV, -20.0) == [(5.0, -10.0), (-8.0, 10.0), (0.0, -20.0), (8.0, 0.0)]
    assert offsets(flat, NXSENSOR_FOV, NXSENSOR_FOV.middle_z_mm) == [(0.0, 0.0), (0.0, -15.0)]
    # a 25 mm range: a quarter of the z shifts, y shares of its narrower line
    small = offsets(spheres, RANGE_25, 0.0)
    assert [z for _, z in small] == pytest.approx([-2.5, 2.5, -5.0, 0.0])
    assert [y for y, _ in small] == pytest.approx([1.5, -2.4, 0.0, 2.4])  # the line is 12 mm wide at z = 0
    # an offset in mm is the user's, field of view or not
    from spherecal.config import SweepSite

    assert offsets([SweepSite(offset_mm=(1.0, -2.0))], None, 0.0) == [(1.0, -2.0)]
    assert offsets([SweepSite()], None, 0.0) == [(0.0, 0.0)]
    with pytest.raises(ConfigError, match=r"validation.offset_mm: not set, and the sensor type declares no field of "
                                          r"view to size offset_percent \(12.5, -10.0\) in"):
        offsets(spheres[:1], None, 0.0)
