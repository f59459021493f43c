"""``spherecal compare``: the difference between two calibrations, or a calibration and a
given transform, and whether it is drift; and the transform given on the command line
(compare, validate), read with the run's robot plugins."""

from __future__ import annotations

from pathlib import Path

from spherecal.app import plugin_host
from spherecal.core.errors import ConfigError
from spherecal.devices.contract import ControllerFrame
from spherecal.report import compare as cmp


def given_transform(host, *, transform: str | None, frames: list[tuple[str, str]], frame_words: str,
                    std_mm: float | None = None, std_deg: float | None = None, uncertainty: str = "robot-frame",
                    robot_type: str | None = None) -> cmp.TransformEstimate | None:
    """The transform of ``--transform`` (``transform``) or of a controller frame line
    (``frames``: each given as (option, text)), None when neither is given, with the
    covariance of ``--std-mm``/``--std-deg``. ``host``: the run's plugin host (made here
    when a controller frame needs one and none is given); ``frame_words``: the options
    that take a controller frame, for the messages."""
    if len(frames) + (transform is not None) > 1:
        used = (["--transform"] if transform is not None else []) + [option for option, _ in frames]
        raise ConfigError(f"give one of --transform and {frame_words} (given: {', '.join(used)})")
    hosts = [host] if host is not None else []

    def read_frame(text: str, what: str) -> ControllerFrame:
        if not hosts:
            hosts.append(plugin_host.make_host())
        return cmp.read_controller_frame(text, hosts[0].registry, what, robot_type=robot_type)

    if transform is not None:
        est = cmp.read_transform_argument(transform, read_frame, "--transform", uncertainty=uncertainty)
    elif frames:
        option, text = frames[0]
        est = cmp.estimate_of_frame(read_frame(text, option), option)
    else:
        if std_mm is not None or std_deg is not None:
            raise ConfigError(f"--std-mm and --std-deg are the uncertainty of --transform or {frame_words}: "
                              "give one")
        return None
    if std_mm is not None or std_deg is not None:
        if est.covariance.any():
            raise ConfigError(f"--std-mm/--std-deg: {est.source} has its own covariance; give them only with a "
                              "transform given as numbers or a controller frame")
        est = cmp.TransformEstimate(est.pose, est.transform_name, cmp.covariance_from_std(std_mm or 0.0, std_deg or 0.0),
                                    est.source, est.note, est.arm_model)
    return est


def run_compare(a: str | Path, b: str | Path | None, host, *, transform: str | None = None,
                frames: list[tuple[str, str]] = (), frame_words: str = "--controller-frame",
                std_mm: float | None = None, std_deg: float | None = None, uncertainty: str = "robot-frame",
                threshold_mm: float = cmp.THRESHOLD_MM, threshold_deg: float = cmp.THRESHOLD_DEG,
                significance_level: float = cmp.SIGNIFICANCE_LEVEL) -> cmp.Comparison:
    """``spherecal compare``: result ``a`` (a result.json or run folder) against result
    ``b`` or the transform given (:func:`given_transform`): exactly one of them."""
    result, where = cmp.read_result_operand(a)
    reference = cmp.TransformEstimate.of_result(result, str(where), uncertainty)
    given = given_transform(host, transform=transform, frames=list(frames), frame_words=frame_words, std_mm=std_mm,
                            std_deg=std_deg, uncertainty=uncertainty)
    if (b is None) == (given is None):
        raise ConfigError(f"compare A with one of: a second result (B), --transform or {frame_words}")
    if given is None:
        other, where_b = cmp.read_result_operand(b)
        given = cmp.TransformEstimate.of_result(other, str(where_b), uncertainty)
    return cmp.compare(reference, given, threshold_mm=threshold_mm, threshold_deg=threshold_deg,
                       significance_level=significance_level)
