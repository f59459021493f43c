"""``spherecal simulate OUT``: calls :mod:`spherecal.app.simulate` and says what it wrote."""

from __future__ import annotations

from spherecal.app.simulate import configured_cell, standard_cell_for, write_simulated, write_simulated_recording
from spherecal.cli.output import EXIT_OK
from spherecal.cli.parser import SIMULATE_DEFAULTS, flag
from spherecal.cli.session import Session
from spherecal.core.errors import ConfigError


def run(args, session: Session) -> int:
    if args.on_the_fly and args.profiles is not None:
        raise ConfigError("--profiles: profiles per station are for stop-and-go shots; an on-the-fly recording "
                          "sweeps continuously and takes a profile at every exposure; leave --profiles out")
    if args.config:
        # the configuration gives the cell and the plan: an option that would change them is refused, never ignored
        clash = [flag(name) for name in ("sensor", *SIMULATE_DEFAULTS) if name != "seed"
                 and getattr(args, name) is not None]
        if clash:
            raise ConfigError(f"{', '.join(clash)}: the configuration gives the sensor, the mounting, the plan and "
                              "the noise ([sensor], mounting, [acquisition], [simulation]); give these options "
                              "without --config, or change the configuration")
        cell, plan, provenance = configured_cell(args.config, seed=args.seed)
    else:
        given = {name: default if getattr(args, name) is None else getattr(args, name)
                 for name, default in SIMULATE_DEFAULTS.items()}
        cell, plan = standard_cell_for(args.sensor, **given)
        provenance = None
    if args.on_the_fly:
        rec = write_simulated_recording(cell, plan, args.out, force=args.force, provenance=provenance)
        session.say(f"wrote an on-the-fly recording ({cell.mounting}) to {args.out}: {rec.poses.n} poses, "
                    f"{rec.profiles.n} profiles, {len(rec.sweeps)} sweeps, "
                    f"{rec.provenance['duration_s']:.1f} s")
        return EXIT_OK
    ds = write_simulated(cell, plan, args.out, force=args.force, provenance=provenance)
    session.say(f"wrote {len(ds.observations)} observations ({cell.mounting}) to {args.out}")
    return EXIT_OK
