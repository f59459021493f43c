import pytest



@pytest.fixture(params=["eye_in_hand", "eye_to_hand"])
def mounting(request):
    return request.param
