"""``examples/graded_index.py --quick``: the inverse-rendering example runs end to end at 8³,
writes its PNG and JSON, and Adam lowers the image loss (it is not asked to, and does not,
recover the field exactly: see the example's docstring)."""

import importlib.util
import json
from pathlib import Path

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "graded_index.py"


def test_quick_run_lowers_the_image_loss(tmp_path, capsys):
    spec = importlib.util.spec_from_file_location("graded_index", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    result = module.main(["--quick", "--out", str(tmp_path)])
    assert (tmp_path / "graded_index.png").stat().st_size > 0
    assert json.loads((tmp_path / "graded_index.json").read_text()) == result
    assert result["image_loss_end"] < 0.5 * result["image_loss_start"]
    assert 0 < result["field_error_end"] < 2
    out = capsys.readouterr().out
    assert out.count("iter ") == result["iterations"] and "field error" in out
