"""The model directory's layout: the names build writes are the names evaluate reads."""

import json

import pytest

from hortishape.errors import HortishapeError
from hortishape.evaluate import evaluate_model
from hortishape.layout import ModelDir


def test_paths_and_built_state(tmp_path):
    d = ModelDir(tmp_path / "m")
    assert d.registered_mesh("a").relative_to(d.root).as_posix() == "registered/a.ply"
    assert d.aligned_mesh("a").relative_to(d.root).as_posix() == "aligned/a.ply"
    assert d.first_pass.relative_to(d.root).as_posix() == "work/first-pass"
    assert not d.is_built()
    d.root.mkdir()
    d.summary.write_text(json.dumps({"instances": ["a"]}))
    assert not d.is_built()  # no model yet: an interrupted build
    with pytest.raises(HortishapeError, match="not a built model directory"):
        evaluate_model(d.root)
    d.model.write_bytes(b"")
    assert d.is_built()
    assert ModelDir(str(d.root)) == d  # a str and a Path name the same directory
