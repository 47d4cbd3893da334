"""The analytic grid on the ideal device: η, NDF and BRDF against the truth.

GGX and Beckmann, α ∈ {0.05, 0.1, 0.2, 0.4}, η ∈ {1.3, 1.5, 2.0}, k_d ∈ {0, 0.2},
k_s = 0.8: one capture each (seed 1), reconstructed with the default options. Prints
per case the η error, the mean relative NDF error where D > 1 % of its peak (on a 512
hemicube's texel directions), the normalized eq. 10 error (every third θ_d/φ_d bin),
the model error ε, whether the capture was found isotropic, and the time; then how
many cases meet the targets (2 %, 5 %, 1 %). Then six anisotropic GGX cases: found
anisotropic, and the NDF within 8 %.

Run: ``.venv/bin/python studies/validate_reconstruction.py [--bits N]`` (≈ 2 minutes).
``--bits 16`` gives the ideal device a 16-bit ADC instead of its 12 bits: the rounding of
a flat diffuse floor is then 16× finer (a diagnostic; the acceptance is the 12-bit device).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from reflecto import workflow
from reflecto.evaluate.metrics import brdf_error, ndf_error
from reflecto.instrument.device import Device
from reflecto.instrument.simulate import simulate_capture
from reflecto.reconstruct import reconstruct
from reflecto.sources.analytic import AnalyticBRDF


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bits", type=int, default=None, help="ADC bit depth of the ideal camera (default: its 12)")
    args = ap.parse_args()
    dev = Device.builtin("ideal")
    if args.bits is not None:
        dev = dev.with_camera(bits=args.bits)
    cal = workflow.calibration_for(dev, missing="nominal")
    ok = np.zeros(3, int)
    n = own = 0
    for dist in ("ggx", "beckmann"):
        for alpha in (0.05, 0.1, 0.2, 0.4):
            for eta in (1.3, 1.5, 2.0):
                for kd in (0.0, 0.2):
                    src = AnalyticBRDF(distribution=dist, alpha=alpha, kd=kd, ks=0.8, eta=eta)
                    sl = workflow.measure(simulate_capture(src, dev, seed=1), cal)
                    t = time.perf_counter()
                    res = reconstruct(sl)
                    t = time.perf_counter() - t
                    m = res.model
                    e_eta = float(np.max(np.abs(m.eta / eta - 1)))
                    e_ndf = ndf_error(src, m, resolution=512)
                    e_brdf = brdf_error(src, m, stride=3).normalized
                    ok += [e_eta <= 0.02, e_ndf <= 0.05, e_brdf <= 0.01]
                    n += 1
                    form = res.shadowing.form if res.shadowing is not None else "-"
                    own += form == "separable"  # these lobes' own form: Smith's separable product
                    print(f"{dist:8s} α={alpha:<4} η={eta:<3} k_d={kd:<3}  η err {100 * e_eta:4.1f} %  "
                          f"NDF {100 * e_ndf:4.1f} %  BRDF {100 * e_brdf:5.2f} %  ε {res.model_error:.4f}  "
                          f"{'iso' if res.isotropic else 'ANISO'}  S {form:17s}  {1000 * t:5.0f} ms", flush=True)
    print(f"within target: η {ok[0]}/{n}, NDF {ok[1]}/{n}, BRDF {ok[2]}/{n}; the lobes' own (separable) shadowing "
          f"form kept on {own}/{n}")
    # acceptance 2: anisotropic GGX, α_x/α_y up to 4, rotated tangents; NDF within 8 %
    n_ok = 0
    cases = [((0.1, 0.2), 0), ((0.05, 0.2), 75), ((0.2, 0.05), 120), ((0.1, 0.4), 30), ((0.4, 0.1), 0),
             ((0.1, 0.4), 60)]
    for alpha, rot in cases:
        src = AnalyticBRDF(distribution="ggx", alpha=alpha, rotation_deg=rot, kd=0.1, ks=0.7, eta=1.5)
        res = reconstruct(workflow.measure(simulate_capture(src, dev, seed=1), cal))
        m = res.model
        e_ndf = ndf_error(src, m, resolution=512)
        n_ok += e_ndf <= 0.08 and not res.isotropic
        print(f"anisotropic GGX α={alpha} rotated {rot:3d}°  {'iso' if res.isotropic else 'aniso'} "
              f"(2nd harmonic {100 * res.isotropy.anisotropy:.0f} %)  NDF {100 * e_ndf:4.1f} %  "
              f"k_s {m.ks[1]:.3f} (0.7)  "
              f"BRDF {100 * brdf_error(src, m, stride=3).normalized:5.2f} %", flush=True)
    print(f"anisotropic, detected and within 8 %: {n_ok}/{len(cases)}")


if __name__ == "__main__":
    main()
