"""commands._args: the CLI's --up / --root strings become typed values before the pipeline."""
import argparse

import numpy as np
import pytest

from leaffit_usd.commands._args import add_frame_arguments, frame_options, parse_root, parse_up
from leaffit_usd.errors import ParameterError, UserError


def test_parse_up():
    np.testing.assert_allclose(parse_up("-y"), [0, -1, 0])
    np.testing.assert_allclose(parse_up("0,0,2"), [0, 0, 1])
    assert parse_up("auto") is None and parse_up(None) is None
    for bad in ("w", "0,0,0", "1,2", "nan,0,1"):
        with pytest.raises(UserError):
            parse_up(bad)


def test_parse_root():
    assert parse_root("auto") is None and parse_root(None) is None
    np.testing.assert_allclose(parse_root(" 1, -2.5,3 "), [1, -2.5, 3])
    for bad in ("1,2", "a,b,c", "1,2,nan"):
        with pytest.raises(ParameterError, match="--root"):
            parse_root(bad)


def test_frame_options_from_the_parser():
    p = argparse.ArgumentParser()
    add_frame_arguments(p)
    kw = frame_options(p.parse_args(["--up=-z", "--root", "0,0,1"]))
    np.testing.assert_allclose(kw["up"], [0, 0, -1])
    np.testing.assert_allclose(kw["root"], [0, 0, 1])
    assert kw["root_index"] is None
    assert frame_options(p.parse_args([])) == {"up": None, "root": None, "root_index": None}
