"""The one-pass MCAP reader (spherecal.io.mcap_scan) gives what rosbags gives, or steps
aside: a bag converts to the same recording whichever reader took it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import spherecal.io.rosbag as rosbag_module
from spherecal.io.mcap_scan import NotPlain, scan_messages
from spherecal.io.rosbag import read_bag

from bag_files import make_truth, pose_messages, profile_messages, write_bag

CLOUD = "sensor_msgs/msg/PointCloud2"
POSE = "geometry_msgs/msg/PoseStamped"


def _bag(tmp_path, **kw):
    truth = make_truth(n_profiles=40)
    return write_bag(tmp_path / "bag", "mcap", {"/profiles": (CLOUD, profile_messages(truth)),
                                                "/pose": (POSE, pose_messages(truth)),
                                                "/other": (POSE, pose_messages(truth)[:5])}, **kw)


def _read(bag):
    return read_bag(bag, profile_topic="/profiles", pose_topic="/pose", mounting="eye_in_hand",
                    sphere_radius_mm=19.05)


def _through_rosbags(bag, monkeypatch):
    def refuse(files, counts):
        raise NotPlain
        yield  # a generator, as the real one

    with monkeypatch.context() as m:
        m.setattr(rosbag_module, "scan_messages", refuse)
        return _read(bag)


def _assert_same(a, b):
    for stream in ("profiles", "poses"):
        for f in dataclasses.fields(getattr(a, stream)):
            x, y = getattr(getattr(a, stream), f.name), getattr(getattr(b, stream), f.name)
            if x is None or y is None:
                assert x is y, f"{stream}.{f.name}"
            else:
                np.testing.assert_array_equal(x, y, err_msg=f"{stream}.{f.name}")
                assert np.asarray(x).dtype == np.asarray(y).dtype, f"{stream}.{f.name}"
    assert a.provenance == b.provenance and a.clocks == b.clocks


def _counts(bag):
    from rosbags.rosbag2 import Reader

    with Reader(bag) as r:
        return {c.topic: c.msgcount for c in r.connections if c.topic in ("/profiles", "/pose")}


@pytest.mark.parametrize("compression", [None, "storage"], ids=["plain chunks", "zstd chunks"])
def test_the_one_pass_reader_gives_what_rosbags_gives(tmp_path, monkeypatch, compression):
    bag = _bag(tmp_path, compression=compression)
    (mcap,) = bag.glob("*.mcap")
    counts = _counts(bag)
    taken = list(scan_messages([mcap], counts))  # the one pass reads this bag (it does not step aside)
    assert [t for t, _, _ in taken].count("/profiles") == counts["/profiles"] == 40
    _assert_same(_read(bag), _through_rosbags(bag, monkeypatch))


def test_message_compression_and_a_topic_out_of_log_order_go_through_rosbags(tmp_path, monkeypatch):
    bag = _bag(tmp_path / "m", compression="message")
    _assert_same(_read(bag), _through_rosbags(bag, monkeypatch))

    truth = make_truth(n_profiles=40)
    clouds = profile_messages(truth)
    clouds[3], clouds[4] = clouds[4], clouds[3]  # written out of log-time order: a reader sorts them back
    bag = write_bag(tmp_path / "o" / "bag", "mcap", {"/profiles": (CLOUD, clouds), "/pose": (POSE, pose_messages(truth))},
                    in_log_order=False)
    (mcap,) = bag.glob("*.mcap")
    with pytest.raises(NotPlain):
        list(scan_messages([mcap], _counts(bag)))
    rec = _read(bag)
    assert np.all(np.diff(rec.profiles.t_sensor_s) > 0)  # in log-time order, as rosbags hands them out
    _assert_same(rec, _through_rosbags(bag, monkeypatch))


def test_a_cut_file_or_other_counts_step_aside(tmp_path):
    bag = _bag(tmp_path)
    (mcap,) = bag.glob("*.mcap")
    counts = _counts(bag)
    with pytest.raises(NotPlain):
        list(scan_messages([mcap], {**counts, "/profiles": counts["/profiles"] + 1}))
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 2])
    with pytest.raises(NotPlain):
        list(scan_messages([cut], counts))
    with pytest.raises(NotPlain):
        list(scan_messages([], counts))
