"""pytest's assertion rewriting for the shared helpers (their asserts explain themselves too)."""

import pytest

pytest.register_assert_rewrite("tests.helpers")
