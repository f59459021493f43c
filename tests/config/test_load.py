"""Loading a configuration file: a path the machine cannot expand is the file's mistake,
named by its key and the file (exit 2), before anything runs."""

from __future__ import annotations

import pwd

import pytest

from spherecal.cli import EXIT_USAGE, main

CONFIG = """mounting = "eye_in_hand"
output_dir = "{output_dir}"
replay = "{replay}"
[nominal_transform]
translation_mm = [44.5, -19.8, 166.2]
quaternion_wxyz = [0.02714, -0.96565, 0.25663, 0.03026]
[sphere]
radius_mm = 19.1
[robot]
type = "abb_irb2400"
[sensor]
type = "nxsensor_i"
"""


@pytest.mark.parametrize("field", ["output_dir", "replay"])
def test_a_home_folder_of_an_unknown_user_is_a_configuration_error(tmp_path, capsys, field):
    """``~nonexistentuser/x`` cannot be expanded (no such user): a mistake in the file, so
    a configuration error (exit 2) naming the field and the file, as every other bad key
    is named; never Python's 'Could not determine home directory' as an internal error."""
    try:
        pwd.getpwnam("nonexistentuser")
        pytest.skip("this machine has a user called nonexistentuser")
    except KeyError:
        pass
    paths = {"output_dir": "out", "replay": "data.jsonl"}
    paths[field] = "~nonexistentuser/x" if field == "output_dir" else "~nonexistentuser/data.jsonl"
    cfg = tmp_path / "cell.toml"
    cfg.write_text(CONFIG.format(**paths))
    code = main(["calibrate", str(cfg), "--no-report"])
    err = capsys.readouterr().err
    assert "internal error" not in err and "Could not determine home directory" not in err, err
    assert code == EXIT_USAGE, (code, err)
    assert field in err and "cell.toml" in err and "nonexistentuser" in err, err
