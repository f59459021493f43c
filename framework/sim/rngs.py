"""Random-number streams of the simulated devices.

Every simulated device (the controller, the sensor, a pose-stream or profile-stream
server) draws from a generator of its own, spawned from the run's seed by a stable key
(the device's name), through :class:`numpy.random.SeedSequence`. A seeded run then gives
the same numbers whatever the order in which the devices draw: asking one device for an
extra reading never shifts another's noise, as it would were all of them to share one
generator.
"""

from __future__ import annotations

import hashlib

import numpy as np


def stable_key(name: str) -> int:
    """A 32-bit number for ``name``, the same in every process and on every machine
    (Python's ``hash`` of a string changes between processes)."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"a device's random stream needs a non-empty name, got {name!r}")
    return int.from_bytes(hashlib.blake2b(name.encode("utf-8"), digest_size=4).digest(), "little")


def device_rng(seed: int | None, device: str, *subkeys: int) -> np.random.Generator:
    """The generator of the simulated device ``device`` in a run seeded ``seed`` (None:
    0), optionally narrowed by non-negative integers ``subkeys`` (a standstill's pose, a
    sweep's number). Two calls with the same arguments give generators that draw the
    same numbers; different devices' streams are independent."""
    keys = [stable_key(device)]
    for k in subkeys:
        k = int(k)
        if k < 0:
            raise ValueError(f"device_rng({device!r}): subkeys must be non-negative integers, got {k}")
        keys.append(k)
    return np.random.default_rng(np.random.SeedSequence(entropy=int(seed or 0), spawn_key=tuple(keys)))
