"""``spherecal compare A [B]``: calls :mod:`spherecal.app.compare` and prints the
comparison."""

from __future__ import annotations

from spherecal.app.compare import run_compare
from spherecal.cli.output import EXIT_DRIFT, EXIT_OK, transform_json
from spherecal.cli.session import Session
from spherecal.report.compare import format_comparison


def run(args, session: Session) -> int:
    c = run_compare(args.a, args.b, session.host, transform=args.transform, frames=args.controller_frame or [],
                    frame_words=args.frame_words, std_mm=args.std_mm, std_deg=args.std_deg,
                    uncertainty=args.uncertainty, threshold_mm=args.threshold_mm, threshold_deg=args.threshold_deg,
                    significance_level=args.significance)
    session.say(format_comparison(c))
    session.summary.update(
        verdict={"level": "red" if c.drift else "green",
                 "headline": "drift: the difference exceeds a threshold and is significant" if c.drift
                 else "no drift", "reasons": []},
        transform=transform_json(c.transform_name or "", c.b.pose) | {"source": c.b.source},
        reference=transform_json(c.transform_name or "", c.a.pose) | {"source": c.a.source},
        comparison=c.as_dict(),
    )
    if c.drift and args.fail_on_drift:
        session.err("drift found (exit 8): see the comparison above")
        return EXIT_DRIFT
    return EXIT_OK
