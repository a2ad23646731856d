"""Property: the config and data loaders turn any malformed input into an MSAMError (the
package's documented error type), never another exception."""
import string

import numpy as np
import pandas as pd
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from msam_torch.config.schema import load_config
from msam_torch.config.to_spec import to_spec
from msam_torch.data.loading import load_datasets
from msam_torch.errors import MSAMError
from tests.helpers import measured_case

SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
CONFIG, FRAME = measured_case("harmonic", every=20)
KEYS = ["model", "data", "adaptation", "states", "inputs", "parameters", "equations", "target", "components",
        "term", "theta", "adjustments", "file", "time", "columns", "window", "derivatives", "train", "validation",
        "start", "stop", "by", "round_robin_steps", "theta", "normalize", "x", "u", "t", "x_dot"]
scalars = st.one_of(st.none(), st.booleans(), st.integers(-10**6, 10**6), st.floats(allow_nan=True),
                    st.text(max_size=12), st.sampled_from(["abs(x)", "x_dot", "-c/m", "savgol", "x.__class__",
                                                           "1/0", "time", "index", "inf", "nan"]))
trees = st.recursive(scalars, lambda children: st.one_of(
    st.lists(children, max_size=4), st.dictionaries(st.sampled_from(KEYS) | st.text(max_size=6), children, max_size=5)),
    max_leaves=25)


def expect_msam_error(call):
    try:
        call()
    except MSAMError:
        pass


@SETTINGS
@given(text=st.text(alphabet=string.printable, max_size=300))
def test_config_loader_on_random_text(tmp_path, text):
    path = tmp_path / "random.yaml"
    path.write_text(text)
    expect_msam_error(lambda: load_config(path))


@SETTINGS
@given(tree=trees)
def test_config_loader_on_random_structures(tree):
    expect_msam_error(lambda: to_spec(load_config({"model": tree} if not isinstance(tree, dict) else tree).model))


@SETTINGS
@given(path=st.lists(st.sampled_from(["model", "data", "adaptation", "equations", "columns", "window", "x", "[0]"]),
                     min_size=1, max_size=4), value=st.text(max_size=20))
def test_overrides_on_a_valid_config(path, value):
    def load():
        config = load_config(CONFIG, [".".join(path) + "=" + value])
        to_spec(config.model)

    expect_msam_error(load)


def test_overrides_index_the_lists_of_a_config():
    """``[i]`` and ``.i`` reach a list item that exists; an index past the list names the key."""
    config = load_config(CONFIG, ["model.equations[0].components[1].theta=-2.5", "model.equations.0.adjustments=[abs(x)]"])
    assert config.model.equations[0].components[1].theta == -2.5
    assert config.model.equations[0].adjustments == ["abs(x)"]
    try:
        load_config(CONFIG, ["model.equations[3].target=x_ddot"])
    except MSAMError as error:
        assert "model.equations[3].target" in str(error) and "the list has 1 items" in str(error)
    else:
        raise AssertionError("an index past the list loaded")


def corrupt(draw_frame: pd.DataFrame, data, kind: str) -> pd.DataFrame:
    frame = draw_frame.copy()
    column = data.draw(st.sampled_from(list(frame.columns)))
    rows = data.draw(st.lists(st.integers(0, len(frame) - 1), min_size=1, max_size=5))
    if kind == "value":
        value = data.draw(st.sampled_from([np.nan, np.inf, -np.inf, "abc", "", None, 0.0, 1e308]))
        frame[column] = frame[column].astype(object)
        frame.loc[rows, column] = value
    elif kind == "drop":
        frame = frame.drop(columns=[column])
    elif kind == "rows":
        frame = frame.iloc[data.draw(st.integers(0, 8)):data.draw(st.integers(0, len(frame)))]
    elif kind == "shuffle":
        frame = frame.sample(frac=1.0, random_state=data.draw(st.integers(0, 1000)))
    elif kind == "constant":
        frame[column] = data.draw(st.floats(-10, 10))
    return frame


@SETTINGS
@given(data=st.data(), kind=st.sampled_from(["value", "drop", "rows", "shuffle", "constant"]),
       as_csv=st.booleans(), window=st.one_of(st.none(), st.integers(3, 99)),
       derivatives=st.sampled_from(["savgol", "spline", "loess", "finite_difference", "exact"]))
def test_data_loaders_on_corrupted_tables(tmp_path, data, kind, as_csv, window, derivatives):
    frame = corrupt(FRAME[["t", "x", "u"]], data, kind)
    config = load_config({**CONFIG, "data": {"file": "data.csv", "time": "t", "columns": {"x": "x", "u": "u"},
                                             "derivatives": derivatives, "window": window}})
    spec = to_spec(config.model)

    def load():
        if as_csv:
            frame.to_csv(tmp_path / "data.csv", index=False)
            load_datasets(config.data, spec, tmp_path)
        else:
            load_datasets(config.data, spec, tmp_path, frame=frame)

    expect_msam_error(load)


@SETTINGS
@given(content=st.binary(max_size=200), suffix=st.sampled_from([".csv", ".parquet", ".txt"]))
def test_data_loader_on_random_bytes(tmp_path, content, suffix):
    (tmp_path / f"data{suffix}").write_bytes(content)
    config = load_config({**CONFIG, "data": {"file": f"data{suffix}", "time": "t", "columns": {"x": "x", "u": "u"},
                                             "derivatives": "savgol"}})
    expect_msam_error(lambda: load_datasets(config.data, to_spec(config.model), tmp_path))
