import re
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


#: The example cells' simulated arm error section (removed by ``exact_arm=True``).
ROBOT_ERROR_SECTION = r"(?m)^\[simulation\.robot_error\]\n(?:[a-z_]+ = .*\n)+"


def example_config(tmp_path: Path, name: str, exact_arm: bool = False, **replace: str) -> Path:
    """A copy of an example configuration writing into tmp_path; ``replace`` maps a
    regular expression to its replacement in the text. ``exact_arm``: without the
    simulated arm's geometric error (for tests of figures in a clean cell), and with the
    station robot error model, which costs no precision on an exact arm (the kinematic
    model's stated prior of an uncalibrated arm does, most in eye-to-hand)."""
    text = (EXAMPLES / name).read_text()
    if exact_arm:
        text, n = re.subn(ROBOT_ERROR_SECTION, "", text)
        assert n == 1, f"no [simulation.robot_error] section in {name}"
        text, n = re.subn(r"(?m)^\[calibration\]\n", '[calibration]\nrobot_error_model = "station"\n', text)
        if n == 0:
            text += '\n[calibration]\nrobot_error_model = "station"\n'

    text = re.sub(r'(?m)^output_dir = .*$', 'output_dir = "out"', text)
    for pattern, repl in replace.items():
        text, n = re.subn(pattern, repl, text, flags=re.M)
        assert n, f"pattern {pattern!r} not found in {name}"
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.fixture
def sim_config(tmp_path):
    return lambda name="sim-eye-in-hand.toml", **kw: example_config(tmp_path, name, **kw)
