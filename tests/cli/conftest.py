import re
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def example_config(tmp_path: Path, name: str, **replace: str) -> Path:
    """A copy of an example configuration writing into tmp_path; ``replace`` maps a
    regular expression to its replacement in the text."""
    text = (EXAMPLES / name).read_text()
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
