import pytest

from spherecal.io import observation_line


@pytest.fixture(params=["eye_in_hand", "eye_to_hand"])
def mounting(request):
    return request.param


@pytest.fixture(params=["orjson", "stdlib"])
def parser(request, monkeypatch):
    """Run a test with the orjson accelerator and with the standard library's json."""
    if request.param == "orjson":
        if observation_line._orjson is None:
            pytest.skip("orjson not installed")
    else:
        monkeypatch.setattr(observation_line, "_orjson", None)
    return request.param
