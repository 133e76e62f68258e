"""Random input at volume: Hypothesis draws command lines of ``key=value`` overrides.

Every draw is composed and checked as ``train`` does before it imports torch
(``config.compose.compose_run_config``, ``validation.validate``): it is accepted or refused by
one of the errors the command line turns into one line and exit status 2. Any other exception
would reach the user as a traceback, and fails the test with the draw that made it. A switch
(a boolean field) is accepted only with a yes or a no: OmegaConf alone took any integer.
The slow tier trains every accepted draw on a tiny budget (the draw's budget keys replaced)
and draws the other scripts' arguments against a trained policy: each ends with exit status 0,
or 2 with one line and nothing written.
"""

from __future__ import annotations

import pytest
from hydra.errors import HydraException
from omegaconf.errors import OmegaConfBaseException

from tests.conftest import SMOKE_OVERRIDES, run_script_in_process
from trl_cartpole.cli.main import one_line
from trl_cartpole.config.compose import compose_run_config
from trl_cartpole.config.presets import PRESETS_DIR
from trl_cartpole.config.schema import Config, flat_fields, to_config
from trl_cartpole.config.validation import BOOLEAN_WORDS, validate
from trl_cartpole.errors import ConfigError

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


def drawn(examples: int) -> settings:
    """Hypothesis settings for ``examples`` draws, the same on every run and machine
    (``derandomize``, and no example database replaying earlier failures first)."""
    return settings(
        max_examples=examples,
        deadline=None,
        derandomize=True,
        database=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
    )


def check(overrides: list[str]) -> str:
    """``accepted`` or ``refused``; any other exception propagates to the test."""
    try:
        validate(to_config(compose_run_config(PRESETS_DIR, [*overrides, "run_dir=unused"])))
    except REFUSALS as error:
        message = one_line(error)
        assert message and "\n" not in message, (overrides, message)
        return "refused"
    for override in overrides:  # a switch is set by a yes or a no, not by any number
        key, _, value = override.partition("=")
        assert key not in SWITCHES or value.lower() in BOOLEAN_WORDS, overrides
    return "accepted"


@pytest.mark.slow  # 200 drawn command lines
@drawn(200)  # about 25 s here
@given(OVERRIDES)
def test_every_drawn_command_line_is_accepted_or_refused_in_one_line(overrides):
    OUTCOMES[check(overrides)] += 1


@pytest.fixture(autouse=True, scope="module")
def report_outcomes():
    """Print the count of each outcome (``pytest -s tests/test_fuzz.py``: docs/reliability.md)."""
    yield
    print(f"\ndrawn command lines: {OUTCOMES}")


# --- the slow tier: accepted draws trained, the other scripts' arguments drawn ---------------

# The budget a drawn command line is trained with: it replaces the draw's own budget keys
# (a drawn collector.total_frames may be 2**62), the rest of the draw stands.
TINY_BUDGET = [
    "collector.total_frames=256",
    "collector.init_random_frames=64",
    "eval.interval_frames=128",
    "eval.episodes=2",
    "eval.final_episodes=2",
    "eval.max_steps=200",
    "env.normalization_frames=200",
    "checkpoint.interval_frames=128",
    "logger.plots=false",
    "logger.live_plot=false",
    "logger.progress_bar=false",
]
BUDGET_KEYS = {override.split("=", 1)[0] for override in TINY_BUDGET}
TRAINED: dict[str, int] = {"refused": 0, "trained": 0, "refused_when_built": 0}
SCRIPT_OUTCOMES: dict[str, int] = {"ran": 0, "refused": 0}


def _one_error_line(proc) -> str:
    lines = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr[-2000:]
    return lines[0]


@pytest.mark.slow  # trains each accepted draw: about 2 s each
@drawn(200)
@given(overrides=OVERRIDES)
def test_every_accepted_draw_trains_a_tiny_budget_and_a_refusal_writes_nothing(
    overrides, tmp_path_factory
):
    drawn = [override for override in overrides if override.split("=", 1)[0] not in BUDGET_KEYS]
    command = [*SMOKE_OVERRIDES, *drawn, *TINY_BUDGET]
    if not drawn or check(command) == "refused":
        TRAINED["refused"] += 1
        return
    run_dir = tmp_path_factory.mktemp("draw") / "run"
    proc = run_script_in_process("train.py", *command, f"run_dir={run_dir}")
    if proc.returncode == 2:  # refused once built (the memory check, an env that cannot be made)
        _one_error_line(proc)
        assert not run_dir.exists(), (command, sorted(run_dir.rglob("*")))
        TRAINED["refused_when_built"] += 1
        return
    assert proc.returncode == 0, (command, proc.stderr[-2000:])
    assert (run_dir / "summary.json").is_file()
    TRAINED["trained"] += 1


@pytest.fixture(scope="module")
def trained_policy(tmp_path_factory) -> str:
    run_dir = tmp_path_factory.mktemp("trained") / "run"
    proc = run_script_in_process("train.py", *SMOKE_OVERRIDES, f"run_dir={run_dir}")
    assert proc.returncode == 0, proc.stderr[-2000:]
    return str(run_dir)


SCRIPT_VALUES = st.one_of(
    st.integers(min_value=-(2**70), max_value=2**70).map(str),
    st.integers(min_value=-2, max_value=30).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(["null", "true", "false", "[]", "{}", "${nope}", "'", ",", "", "1e400"]),
    st.text(alphabet=st.characters(codec="ascii", exclude_categories=["Cc"]), max_size=8),
)
# Each script's arguments that take values (paths are set by the test: a drawn path would
# write where it likes).
SCRIPT_ARGUMENTS = {
    "evaluate.py": ["episodes", "seed", "epsilon"],
    "render.py": ["episodes", "seed", "fps", "scale"],
}


@pytest.mark.slow  # evaluates or renders each accepted draw
@drawn(100)
@given(
    script_and_arguments=st.sampled_from(sorted(SCRIPT_ARGUMENTS)).flatmap(
        lambda script: st.tuples(
            st.just(script),
            st.lists(
                st.tuples(st.sampled_from(SCRIPT_ARGUMENTS[script]), SCRIPT_VALUES),
                min_size=1,
                max_size=3,
                unique_by=lambda item: item[0],
            ),
        )
    )
)
def test_drawn_arguments_of_evaluate_and_render_run_or_are_refused_in_one_line(
    script_and_arguments, trained_policy, tmp_path_factory
):
    script, arguments = script_and_arguments
    name = "report.json" if script == "evaluate.py" else "a.gif"
    output = tmp_path_factory.mktemp("out") / name
    proc = run_script_in_process(
        script,
        f"checkpoint={trained_policy}",
        f"output={output}",
        *(f"{key}={value}" for key, value in arguments),
    )
    if proc.returncode == 2:
        _one_error_line(proc)
        assert not output.exists()
        SCRIPT_OUTCOMES["refused"] += 1
        return
    assert proc.returncode == 0, (script, arguments, proc.stderr[-2000:])
    assert output.is_file()
    SCRIPT_OUTCOMES["ran"] += 1


@pytest.fixture(autouse=True, scope="module")
def report_trained():
    yield
    if any(TRAINED.values()):
        print(f"\ntrained draws: {TRAINED}")
    if any(SCRIPT_OUTCOMES.values()):
        print(f"\nevaluate and render draws: {SCRIPT_OUTCOMES}")
