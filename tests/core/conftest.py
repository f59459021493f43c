import pytest

from spherecal.io import dataset as dataio


@pytest.fixture(params=["eye_in_hand", "eye_to_hand"])
def mounting(request):
    return request.param


@pytest.fixture(params=["orjson", "stdlib"])
def parser(request, monkeypatch):
    """Run a test with the orjson accelerator and with the standard library's json."""
    if request.param == "orjson":
        if dataio._orjson is None:
            pytest.skip("orjson not installed")
    else:
        monkeypatch.setattr(dataio, "_orjson", None)
    return request.param
