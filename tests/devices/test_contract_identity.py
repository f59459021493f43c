"""spherecal.devices.contract.device_identity: what a device says it is, never a reason to stop."""

from spherecal.devices.contract import device_identity


class _Says:
    def __init__(self, answer):
        self.answer = answer

    def identity(self):
        if isinstance(self.answer, Exception):
            raise self.answer
        return self.answer


def test_known_keys_are_kept_in_order_as_strings():
    got = device_identity(_Says({"serial_number": 123, "model": "X-1", "colour": "red", "firmware": ""}))
    assert got == {"model": "X-1", "serial_number": "123"}
    assert device_identity(_Says({"model": "m" * 500}))["model"] == "m" * 200


def test_a_device_without_identity_or_with_a_failing_one_reports_nothing():
    assert device_identity(object()) == {}
    assert device_identity(_Says(RuntimeError("USB stalled"))) == {}
    assert device_identity(_Says(["not", "a", "mapping"])) == {}
