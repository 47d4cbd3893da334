"""conftest's dependency helpers: a missing dependency that ``make test`` installs skips a
test locally and fails it under ``CI=true``."""

import pytest

from conftest import in_ci, require


@pytest.mark.parametrize("value, ci", [("true", True), ("1", True), ("TRUE", True), ("", False), ("false", False)])
def test_ci_is_read_from_the_environment(monkeypatch, value, ci):
    monkeypatch.setenv("CI", value)
    assert in_ci() is ci


def test_a_missing_dependency_skips_locally_and_fails_in_ci(monkeypatch):
    absent = "reflecto_no_such_module_or_binary_42"
    monkeypatch.delenv("CI", raising=False)
    with pytest.raises(pytest.skip.Exception, match=absent):
        require(absent)
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception, match=f"{absent}.*CI=true"):
        require(absent)


def test_a_present_dependency_is_returned(monkeypatch):
    monkeypatch.setenv("CI", "true")
    import json

    assert require("json") is json  # a module comes back imported
    assert require("reflecto_no_such_module_42", "sh").endswith("/sh")  # else the first executable found
