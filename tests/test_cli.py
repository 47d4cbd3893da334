import json
import subprocess
import sys

import numpy as np

from reflecto.cli import main
from reflecto.sources import merl


def test_info_json(capsys, shared):
    assert main(["info", str(shared / "merl-nbrdf" / "pvc.h5"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["kind"] == "nbrdf" and info["reciprocal"]
    lo, hi = info["albedo_range"]
    assert 0 < lo <= hi < 1.05


def test_tabulate_analytic(tmp_path, capsys):
    src = tmp_path / "g.json"
    src.write_text('{"type": "analytic", "distribution": "ggx", "alpha": 0.3, "kd": 0.2, "ks": 0.5}')
    out = tmp_path / "g.binary"
    assert main(["tabulate", str(src), "-o", str(out), "-q"]) == 0
    t = merl.read_merl_table(out)
    assert t.shape == (90, 90, 180, 3) and np.all(t >= 0)
    # the diffuse floor 0.2/π lies under every bin above the horizon; the peak is at θ_h ≈ 0
    assert t[t > 0].min() >= 0.2 / np.pi - 1e-12
    from reflecto import geometry as g
    from reflecto.sources import load_source

    th, td, pd = merl.bin_centres()
    i, o = g.hd_to_io(th[0], 0.0, td[10], pd[30])
    assert np.allclose(t[0, 10, 30], load_source(src).eval(i[None], o[None])[0], rtol=1e-12)
    assert t[0, 10, 30, 0] > 1.2 * t[60, 10, 30, 0]  # specular peak above the off-specular floor


def test_bad_input_exits_nonzero_and_writes_nothing(tmp_path, capsys):
    bad = tmp_path / "bad.binary"
    bad.write_bytes(np.array([90, 90, 180], "<i4").tobytes() + b"\x00" * 800)
    out = tmp_path / "out.binary"
    assert main(["tabulate", str(bad), "-o", str(out)]) == 1
    err = capsys.readouterr().err
    assert "bad.binary" in err and "truncated" in err
    assert not out.exists() and not list(tmp_path.glob("*.part"))
    assert main(["info", str(tmp_path / "missing.bsdf")]) == 1
    assert "no such file" in capsys.readouterr().err


def test_console_script_runs():
    r = subprocess.run([sys.executable, "-m", "reflecto.cli", "--version"], capture_output=True, text=True)
    assert r.returncode == 0 and "reflecto" in r.stdout
