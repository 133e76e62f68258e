"""Random input at volume: Hypothesis draws command lines of ``key=value`` overrides.

Every draw is composed and checked as ``train`` does before it imports torch
(``cli.compose_run_config`` and ``validation.validate``): it is either accepted or refused by
one of the errors the command line turns into one line and exit status 2. Any other exception
would reach the user as a traceback, and fails the test with the draw that made it. A switch
(a boolean field) is accepted only with a yes or a no: OmegaConf alone took any integer.
Accepted draws are not trained here (a drawn budget may be any size).
"""

from __future__ import annotations

import pytest
from hydra.errors import HydraException
from omegaconf.errors import OmegaConfBaseException

from trl_cartpole.cli import _one_line, compose_run_config
from trl_cartpole.config import Config, flat_fields, to_config
from trl_cartpole.errors import ConfigError
from trl_cartpole.presets import PRESETS_DIR
from trl_cartpole.validation import BOOLEAN_WORDS, validate

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

# Every field of the schema but run_dir (a draw must not write where it likes).
FIELDS = sorted(key for key in flat_fields(Config()) if key != "run_dir")
SWITCHES = {key for key, value in flat_fields(Config()).items() if isinstance(value, bool)}
REFUSALS = (ConfigError, HydraException, OmegaConfBaseException)
# Values of every type and the edges: huge and negative numbers, NaN and infinities, empty and
# odd strings, lists, null, and text that Hydra's grammar or OmegaConf's interpolation may choke on.
VALUES = st.one_of(
    st.integers(min_value=-(2**70), max_value=2**70).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.booleans().map(lambda flag: str(flag).lower()),
    st.just("null"),
    st.lists(st.integers(min_value=-3, max_value=2**20), max_size=3).map(str),
    st.text(alphabet=st.characters(codec="ascii", exclude_categories=["Cc"]), max_size=12),
    st.sampled_from(
        ["inf", "-inf", "nan", "[]", "{}", "1e400", "${oc.env:HOME}", "${nope}", "'", '"', ","]
    ),
)
OVERRIDES = st.lists(
    st.tuples(st.sampled_from(FIELDS), VALUES).map(lambda item: f"{item[0]}={item[1]}"),
    min_size=1,
    max_size=3,
    unique_by=lambda override: override.split("=", 1)[0],
)
OUTCOMES: dict[str, int] = {"accepted": 0, "refused": 0}


def check(overrides: list[str]) -> str:
    """``accepted`` or ``refused``; any other exception propagates to the test."""
    try:
        validate(to_config(compose_run_config(PRESETS_DIR, [*overrides, "run_dir=unused"])))
    except REFUSALS as error:
        message = _one_line(error)
        assert message and "\n" not in message, (overrides, message)
        return "refused"
    for override in overrides:  # a switch is set by a yes or a no, not by any number
        key, _, value = override.partition("=")
        assert key not in SWITCHES or value.lower() in BOOLEAN_WORDS, overrides
    return "accepted"


@settings(
    max_examples=200,  # about 25 s here
    deadline=None,
    derandomize=True,  # the same draws on every run: a failure is repeatable
    suppress_health_check=[HealthCheck.too_slow],
)
@given(OVERRIDES)
def test_every_drawn_command_line_is_accepted_or_refused_in_one_line(overrides):
    OUTCOMES[check(overrides)] += 1


@pytest.fixture(autouse=True, scope="module")
def report_outcomes():
    """Print the count of each outcome (``pytest -s tests/test_fuzz.py``: docs/reliability.md)."""
    yield
    print(f"\ndrawn command lines: {OUTCOMES}")
