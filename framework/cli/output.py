"""The command line's exit codes and its ``--json`` summary (docs/cli.md)."""

from __future__ import annotations

import json
import math
from pathlib import Path

EXIT_OK = 0
EXIT_INTERNAL = 1
EXIT_USAGE = 2
EXIT_DATA = 3
EXIT_DEVICE = 4
EXIT_VALIDATION = 5
EXIT_PLUGIN = 6
EXIT_RED = 7
EXIT_DRIFT = 8
EXIT_INTERRUPTED = 130
EXIT_PIPE = 141

#: What each exit code means, for the --json summary.
EXIT_MEANING = {
    EXIT_OK: "success", EXIT_INTERNAL: "internal error", EXIT_USAGE: "usage or configuration error",
    EXIT_DATA: "data error", EXIT_DEVICE: "device error", EXIT_VALIDATION: "validation failed",
    EXIT_PLUGIN: "plugin error", EXIT_RED: "the result is RED", EXIT_DRIFT: "drift found",
    EXIT_INTERRUPTED: "interrupted", EXIT_PIPE: "standard output closed by its reader",
}

#: The exit codes as ``spherecal --help`` lists them (scripts may rely on them; docs/cli.md).
EXIT_CODES_HELP = """\
Exit codes (scripts may rely on them; docs/cli.md):
  0  success
  1  internal error (a bug: please report it with the traceback)
  2  usage or configuration error (bad arguments, bad TOML, unknown keys, bad plugin settings)
  3  data error (bad or degenerate data, a plan outside the limits, an unreadable dataset)
  4  device error (robot or sensor: timeout, disconnect, protocol); what was taken is kept
  5  validation failed (an acceptance figure exceeds its MPE)
  6  plugin error (a plugin failed to load or misbehaved)
  7  the result is RED (do not use it): the verdict says why; result.json and the exports
     are written only with --force (the report always)
  8  compare --fail-on-drift: drift found (a difference beyond a threshold and significant)
  130 interrupted (Ctrl-C, or stopped at a --step question); what was taken is kept (calibrate:
      continue with --resume)
  141 standard output closed early by its reader (`spherecal plugins | head`): the rest is
      dropped, no error is printed (128 + SIGPIPE, as a shell reports such a program)
"""

#: Version of the --json summary's layout (docs/cli.md, "Machine-readable output").
JSON_SCHEMA = "spherecal-cli-summary/1"


def transform_json(name: str, pose) -> dict:
    """A transform in the summary: its name, what it maps, translation and quaternion."""
    a, b = name.split("_from_") if name and "_from_" in name else (None, None)
    return {"name": name, "maps": f"points in the {b} frame to the {a} frame" if a else None,
            "translation_mm": list(pose.translation_mm), "quaternion_wxyz": list(pose.quaternion_wxyz),
            "quaternion_order": "w, x, y, z (scalar first, as ABB and result.json)"}


def verdict_json(v) -> dict | None:
    """A verdict in the summary: level, headline and reasons."""
    if v is None:
        return None
    return {"level": v.level, "headline": v.headline,
            "reasons": [{"level": lvl, "text": text} for lvl, text in v.reasons]}


def result_json(result, verdict, written: bool) -> dict:
    """The summary's entries of calibrate and solve: verdict, transform, uncertainty,
    whether the result was written, sphere and residuals."""
    a = result.transform_name.split("_from_")[0]
    unc = {"about": f"the {a} frame's x, y, z axes", "std_rotation_deg": list(result.std_rotation_deg),
           "std_translation_mm": list(result.std_translation_mm), "coverage_factor_k": 2,
           "expanded_rotation_deg": [2 * v for v in result.std_rotation_deg],
           "expanded_translation_mm": [2 * v for v in result.std_translation_mm],
           "std_rotation_deg_robot_frame": None, "std_translation_mm_robot_frame": None,
           "point_error_k2_mm": None, "point_error_nominal_arm_k2_mm": None}
    robot_error = result.robot_error
    if robot_error is not None:
        unc.update(std_rotation_deg_robot_frame=list(robot_error.std_rotation_deg_robot_frame),
                   std_translation_mm_robot_frame=list(robot_error.std_translation_mm_robot_frame),
                   point_error_k2_mm=robot_error.point_error_k2_mm,
                   point_error_nominal_arm_k2_mm=robot_error.point_error_nominal_arm_k2_mm)
    return dict(
        verdict=verdict_json(verdict), transform=transform_json(result.transform_name, result.transform),
        uncertainty=unc, result_written=written,
        sphere={"radius_mm": result.sphere_radius_mm, "radius_fitted": result.radius_fitted,
                "centre_mm": list(result.sphere_centre_mm), "centre_frame": result.sphere_centre_frame},
        residuals={"rms_mm": result.residuals.rms_mm, "points_used": result.residuals.n_points_used,
                   "points_rejected": result.residuals.n_points_rejected},
    )


def json_text(summary: dict) -> str:
    """The summary as strict JSON, its main keys first."""
    order = ["schema", "spherecal", "command", "exit_code", "exit_meaning", "error", "verdict", "transform",
             "uncertainty", "files", "out_dir"]
    ordered = {k: summary[k] for k in order if k in summary} | {k: v for k, v in summary.items() if k not in order}
    return json.dumps(plain(ordered), indent=2, allow_nan=False)


def plain(value):
    """``value`` as plain JSON types: numpy numbers and arrays (anything with ``tolist``)
    as numbers and lists, paths as strings, and a NaN or infinite number as null (JSON
    has none)."""
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if hasattr(value, "tolist"):  # a numpy array or number (numpy itself is not loaded for this)
        return plain(value.tolist())
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, Path):
        return str(value)
    if value is None or isinstance(value, (str, int, float, bool)):
        return value
    return str(value)
