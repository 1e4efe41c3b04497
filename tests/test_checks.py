"""The shared setting checks: ``bool`` is never an int, and the error names the setting."""

import pytest

from iap_mjx.checks import is_int, is_number, require_int


def test_bool_is_neither_int_nor_number():
    assert is_int(3) and is_int(0) and is_int(-2)
    assert not is_int(True) and not is_int(False) and not is_int(2.0) and not is_int(None)
    assert is_number(3) and is_number(0.5)
    assert not is_number(True) and not is_number("1") and not is_number(None)


def test_require_int_names_the_setting_and_the_range():
    require_int("es.population", 1)
    require_int("seed", 0, 0)
    require_int("stride", None, none_ok=True)
    with pytest.raises(ValueError, match=r"^es\.population must be an int >= 1, got 0\.$"):
        require_int("es.population", 0)
    with pytest.raises(ValueError, match=r"^seed must be an int >= 0, got True\.$"):
        require_int("seed", True, 0)
    with pytest.raises(ValueError, match=r"^stride must be an int >= 1 or None, got 2\.5\.$"):
        require_int("stride", 2.5, none_ok=True)
    with pytest.raises(ValueError, match="got None"):
        require_int("stride", None)
