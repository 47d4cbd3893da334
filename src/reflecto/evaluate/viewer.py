"""A BRDF viewer in one static HTML page (what Disney's BRDF Explorer shows, with no install).

:func:`write_viewer` writes ``viewer.html``: the BRDFs' tables are embedded in the page
(base64 float32 in a JSON block), so the page works from ``file://`` with no server and
no network. It shows, for each BRDF side by side (a model and its reference, or two
models):

* a sphere lit by the point lights of Mitsuba's ``sphere-point`` scene (same camera,
  lights and sphere as :mod:`reflecto.render.sphere`, exposure 1); dragging on the sphere
  moves the key light; "environment" lights it by the embedded environment map instead
  (a 32 × 16 latitude–longitude reduction of the studio map, exposed so that the 99th
  luminance percentile shows at 0.9; dragging turns it);
* the θ_h–θ_d slice at a chosen φ_d (log scale), with the BRDF's value under the pointer;
* polar plots of the incidence plane (f·cos θ_o against θ_o) for a chosen θ_i.

**Tables.** Each BRDF is tabulated as the projected BRDF ``f·cos θ_i·cos θ_o`` (smooth and
bounded, :data:`reflecto.brdf.MAX_PROJECTED_BRDF`) on Rusinkiewicz nodes: θ_h at
``u²·90°`` for :data:`N_THETA_H` even steps of ``u`` (dense at the specular peak), θ_d in
:data:`N_THETA_D` even steps to 90°, φ_d in :data:`N_PHI_D` even steps over [0°, 180°]
(``f(φ_d) = f(φ_d + 180°)`` for a reciprocal isotropic BRDF), at φ_h = 0: an anisotropic
BRDF is shown by that slice, as a MERL table holds it. The page interpolates trilinearly:
the spheres the projected value, the slice, its read-out and the polar plots ``f`` itself
(each node's projected value over its own cosines, over the nodes above the horizon).

With ``#test=RES`` in its address the page writes, into ``<pre id="test-output">``, the
linear radiance of each sphere at ``RES²`` pixels (the renders' box filter, 4 × 4
samples per pixel) as JSON, for the tests, and with ``&at=TH,TD,PD;…`` (degrees) the first
BRDF's slice read-out there; ``#light=AZ,EL`` (degrees) places the key light;
``#drag=X,Y`` presses the pointer on the first sphere at ``(X, Y)`` (fractions of its size),
as a user moving the light does.
"""

from __future__ import annotations

import base64
import html
import json
import math
from pathlib import Path

import numpy as np

from .. import geometry
from ..brdf import BRDFSource
from ..io import atomic_write
from ..render.mitsuba import read_envmap
from ..render.sphere import BACKGROUND, CAMERA, FOV_DEG, LIGHTS, TARGET, UP

__all__ = ["N_PHI_D", "N_THETA_D", "N_THETA_H", "tabulate_projected", "write_viewer"]

N_THETA_H = 64
N_THETA_D = 48
N_PHI_D = 32


def tabulate_projected(source: BRDFSource) -> np.ndarray:
    """``f·cos θ_i·cos θ_o`` at the viewer's nodes (module docstring), shape ``(N_θh, N_θd, N_φd, 3)``, float32.

    Nodes: ``θ_h = (π/2) u²`` with ``u`` uniform in [0, 1] (:data:`N_THETA_H`), ``θ_d``
    uniform in [0, π/2] (:data:`N_THETA_D`), ``φ_d`` uniform in [0, π] (:data:`N_PHI_D`),
    ``φ_h = 0``, endpoints included.

    Parameters
    ----------
    source
        The BRDF (sr⁻¹).

    Returns
    -------
    numpy.ndarray of float32, shape (N_THETA_H, N_THETA_D, N_PHI_D, 3)
        The cosine-weighted BRDF (sr⁻¹), clamped at 0; 0 where either direction is at or
        below the horizon.
    """
    u = np.linspace(0.0, 1.0, N_THETA_H)
    th = u * u * (0.5 * math.pi)
    td = np.linspace(0.0, 0.5 * math.pi, N_THETA_D)
    pd = np.linspace(0.0, math.pi, N_PHI_D)
    TH, TD, PD = np.meshgrid(th, td, pd, indexing="ij")
    i, o = geometry.hd_to_io(TH, np.zeros_like(TH), TD, PD)
    i, o = i.reshape(-1, 3), o.reshape(-1, 3)
    ok = (i[:, 2] > 1e-9) & (o[:, 2] > 1e-9)
    out = np.zeros((len(i), 3))
    out[ok] = source.eval(i[ok], o[ok]) * (i[ok, 2] * o[ok, 2])[:, None]
    return np.maximum(out, 0.0).reshape(N_THETA_H, N_THETA_D, N_PHI_D, 3).astype(np.float32)


def _envmap_small(path: Path | None) -> dict | None:
    """The environment map reduced to 32 × 16 (lat–long, linear RGB), or None without one."""
    if path is None or not Path(path).is_file():
        return None
    img = read_envmap(path)  # linear floating point, as Mitsuba's envmap reads it (not 8-bit, not clipped)
    h, w = img.shape[:2]
    small = img[: h - h % 16, : w - w % 32].reshape(16, (h - h % 16) // 16, 32, (w - w % 32) // 32, 3).mean(axis=(1, 3))
    return {"width": 32, "height": 16, "data": base64.b64encode(small.astype("<f4").tobytes()).decode()}


def write_viewer(sources: list[tuple[str, BRDFSource]], path: str | Path, envmap: str | Path | None = None,
                 title: str = "reflecto BRDF viewer") -> Path:
    """Write the viewer page for ``sources`` (``(label, BRDF)`` each, shown side by side).

    Parameters
    ----------
    sources
        One or more ``(label, source)``: a model and its reference, or two models.
    path
        The ``.html`` file to write (atomically).
    envmap
        Environment map (``.hdr``/``.exr``) for the environment lighting; None: point lights only.
    title
        The page's title.

    Returns
    -------
    Path
        ``path``.
    """
    data = {
        "shape": [N_THETA_H, N_THETA_D, N_PHI_D],
        "brdfs": [{"label": label, "table": base64.b64encode(tabulate_projected(src).astype("<f4").tobytes()).decode()}
                  for label, src in sources],
        "camera": {"origin": list(CAMERA), "target": list(TARGET), "up": list(UP), "fov_deg": FOV_DEG},
        "lights": [{"position": list(p), "intensity": float(i)} for p, i in LIGHTS],
        "background": BACKGROUND,
        "envmap": _envmap_small(Path(envmap) if envmap else None),
    }
    # inside <script> the data must not open or close a tag or a comment ("</", "<!--"): every "<" is escaped
    page = _PAGE.replace("%TITLE%", html.escape(title)).replace("%DATA%", json.dumps(data).replace("<", "\\u003c"))
    path = Path(path)
    with atomic_write(path, "w") as fh:
        fh.write(page)
    return path


_PAGE = r"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>%TITLE%</title>
<style>
body{font-family:system-ui,sans-serif;margin:1em;color:#222}
.cols{display:flex;gap:1.5em;flex-wrap:wrap}
.col{border:1px solid #ccc;padding:.6em;border-radius:4px;max-width:240px;font-size:13px}
canvas{display:block;margin:.3em 0;border:1px solid #ddd}
.readout{font-family:monospace;font-size:12px;min-height:1.2em}
label{font-size:13px;margin-right:1em}
</style></head><body>
<h1>%TITLE%</h1>
<p>Drag on a sphere to move the key light (point lights) or turn the environment.
Hover over a θ_h–θ_d slice for the BRDF's value. Tables: f·cos θ_i·cos θ_o on
Rusinkiewicz nodes, embedded in this page.</p>
<div>
<label><input type="radio" name="light" value="point" checked> point lights</label>
<label><input type="radio" name="light" value="env" id="env-radio"> environment</label>
<label>exposure <input type="range" id="exposure" min="-4" max="4" step="0.25" value="0"></label>
<label>slice φ_d <input type="range" id="phid" min="0" max="180" step="5" value="90"> <span id="phid-v">90°</span></label>
<label>polar θ_i <input type="range" id="thetai" min="0" max="85" step="5" value="30"> <span id="thetai-v">30°</span></label>
</div>
<div class="cols" id="cols"></div>
<pre id="test-output"></pre>
<script id="viewer-data" type="application/json">%DATA%</script>
<script>
"use strict";
const D = JSON.parse(document.getElementById("viewer-data").textContent);
const [NH, ND, NP] = D.shape;
function f32(b64) {
  const s = atob(b64), u = new Uint8Array(s.length);
  for (let k = 0; k < s.length; k++) u[k] = s.charCodeAt(k);
  return new Float32Array(u.buffer);
}
const TABLES = D.brdfs.map(b => f32(b.table));
const ENV = D.envmap ? f32(D.envmap.data) : null;
if (!ENV) document.getElementById("env-radio").disabled = true;
const HALF_PI = Math.PI / 2;
const norm = v => { const l = Math.hypot(v[0], v[1], v[2]); return [v[0] / l, v[1] / l, v[2] / l]; };
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
// Rusinkiewicz angles [θ_h, θ_d, φ_d mod π] of local directions (φ_h dropped: the table is at φ_h = 0)
function rusinkiewicz(i, o) {
  let h = [i[0] + o[0], i[1] + o[1], i[2] + o[2]];
  const hl = Math.hypot(h[0], h[1], h[2]);
  if (hl < 1e-12) return null;
  h = [h[0] / hl, h[1] / hl, h[2] / hl];
  const th = Math.acos(Math.min(1, Math.max(-1, h[2]))), ph = Math.atan2(h[1], h[0]);
  const cz = Math.cos(-ph), sz = Math.sin(-ph);
  const x1 = cz * i[0] - sz * i[1], y1 = sz * i[0] + cz * i[1], z1 = i[2];
  const cy = Math.cos(-th), sy = Math.sin(-th);
  const dx = cy * x1 + sy * z1, dy = y1, dz = -sy * x1 + cy * z1;
  const td = Math.acos(Math.min(1, Math.max(-1, dz)));
  let pd = Math.atan2(dy, dx); if (pd < 0) pd += Math.PI; if (pd > Math.PI) pd -= Math.PI;
  return [th, td, pd];
}
// the table's trilinear cell of Rusinkiewicz angles: first node indices and fractions
function cell(th, td, pd) {
  const a = Math.sqrt(Math.min(th / HALF_PI, 1)) * (NH - 1), b = Math.min(td / HALF_PI, 1) * (ND - 1), c = pd / Math.PI * (NP - 1);
  const a0 = Math.min(Math.floor(a), NH - 2), b0 = Math.min(Math.floor(b), ND - 2), c0 = Math.min(Math.floor(c), NP - 2);
  return [a0, b0, c0, a - a0, b - b0, c - c0];
}
// projected BRDF f·cosθi·cosθo at local directions (trilinear in the table): what the spheres integrate
function proj(T, i, o, out) {
  const r = rusinkiewicz(i, o);
  out[0] = out[1] = out[2] = 0;
  if (!r) return out;
  const [a0, b0, c0, fa, fb, fc] = cell(r[0], r[1], r[2]);
  for (let da = 0; da < 2; da++) for (let db = 0; db < 2; db++) for (let dc = 0; dc < 2; dc++) {
    const w = (da ? fa : 1 - fa) * (db ? fb : 1 - fb) * (dc ? fc : 1 - fc);
    if (w === 0) continue;
    const k = (((a0 + da) * ND + (b0 + db)) * NP + (c0 + dc)) * 3;
    out[0] += w * T[k]; out[1] += w * T[k + 1]; out[2] += w * T[k + 2];
  }
  return out;
}
// f itself at Rusinkiewicz angles (φ_h = 0): each node's f (its projected value over its own
// cosines), interpolated over the nodes above the horizon. Dividing the interpolated projected
// value by the point's cosines instead mixes in the zeros of nodes below it: near grazing that
// read f several times too low.
function fRus(T, th, td, pd, out) {
  const [a0, b0, c0, fa, fb, fc] = cell(th, td, pd);
  let wsum = 0;
  out[0] = out[1] = out[2] = 0;
  for (let da = 0; da < 2; da++) for (let db = 0; db < 2; db++) for (let dc = 0; dc < 2; dc++) {
    const w = (da ? fa : 1 - fa) * (db ? fb : 1 - fb) * (dc ? fc : 1 - fc);
    if (w === 0) continue;
    const u = (a0 + da) / (NH - 1), nh = u * u * HALF_PI, nd = (b0 + db) / (ND - 1) * HALF_PI, np = (c0 + dc) / (NP - 1) * Math.PI;
    const p = Math.cos(nh) * Math.cos(nd), q = Math.sin(nh) * Math.sin(nd) * Math.cos(np), c = (p - q) * (p + q);
    if (!(p - q > 1e-6 && p + q > 1e-6)) continue;  // the node's i or o at or below the horizon
    const k = (((a0 + da) * ND + (b0 + db)) * NP + (c0 + dc)) * 3;
    out[0] += w * T[k] / c; out[1] += w * T[k + 1] / c; out[2] += w * T[k + 2] / c; wsum += w;
  }
  if (wsum > 0) { out[0] /= wsum; out[1] /= wsum; out[2] /= wsum; } else out[0] = out[1] = out[2] = NaN;  // no node above
  return out;
}
// camera rays as reflecto.render.sphere.camera_rays (horizontal fov, camera +x to the left)
function cameraRay(u, v) {
  const C = D.camera, o = C.origin, d = norm([C.target[0] - o[0], C.target[1] - o[1], C.target[2] - o[2]]);
  const left = norm(cross(C.up, d)), up2 = cross(d, left), t = Math.tan(C.fov_deg * Math.PI / 360);
  const x = (0.5 - u) * 2 * t, y = (0.5 - v) * 2 * t;
  return [o, norm([x * left[0] + y * up2[0] + d[0], x * left[1] + y * up2[1] + d[1], x * left[2] + y * up2[2] + d[2]])];
}
const state = { mode: "point", keyLight: D.lights[0].position.slice(), envTurn: 0, exposure: 1, phid: 90, thetai: 30 };
function envDirs() {  // the environment's texels as directional lights: (direction, radiance·dω)
  const W = D.envmap.width, H = D.envmap.height, out = [];
  for (let r = 0; r < H; r++) for (let c = 0; c < W; c++) {
    const theta = (r + 0.5) / H * Math.PI, phi = (c + 0.5) / W * 2 * Math.PI + state.envTurn;
    const dw = (2 * Math.PI / W) * (Math.cos(r / H * Math.PI) - Math.cos((r + 1) / H * Math.PI));
    // Mitsuba's lat-long: +y up, u along the azimuth
    const dir = [Math.sin(theta) * Math.sin(phi), Math.cos(theta), -Math.sin(theta) * Math.cos(phi)];
    const k = (r * W + c) * 3;
    out.push([dir, [ENV[k] * dw, ENV[k + 1] * dw, ENV[k + 2] * dw]]);
  }
  return out;
}
// linear radiance (res × res × 3) and coverage of the sphere, ss × ss samples per pixel
function renderSphere(T, res, ss) {
  const rad = new Float32Array(res * res * 3), cov = new Float32Array(res * res), tmp = [0, 0, 0];
  const lights = state.mode === "point"
    ? [{ position: state.keyLight, intensity: D.lights[0].intensity }].concat(D.lights.slice(1)) : null;
  const env = state.mode === "env" ? envDirs() : null;
  for (let row = 0; row < res; row++) for (let col = 0; col < res; col++) {
    let acc0 = 0, acc1 = 0, acc2 = 0, hits = 0;
    for (let sy = 0; sy < ss; sy++) for (let sx = 0; sx < ss; sx++) {
      const [o, d] = cameraRay((col + (sx + 0.5) / ss) / res, (row + (sy + 0.5) / ss) / res);
      const b = dot(d, o), c = dot(o, o) - 1, disc = b * b - c;
      if (disc <= 0) continue;
      const t = -b - Math.sqrt(disc); if (t <= 0) continue;
      hits++;
      const p = [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]], n = p;
      let tg = [-p[1], p[0], 0]; const tl = Math.hypot(tg[0], tg[1]);
      tg = tl > 1e-9 ? [tg[0] / tl, tg[1] / tl, 0] : [1, 0, 0];
      const bt = cross(n, tg), local = v => [dot(v, tg), dot(v, bt), dot(v, n)];
      const lo = local([-d[0], -d[1], -d[2]]);
      if (lo[2] <= 0) continue;
      if (lights) for (const L of lights) {
        const lv = [L.position[0] - p[0], L.position[1] - p[1], L.position[2] - p[2]], r2 = dot(lv, lv), r = Math.sqrt(r2);
        const li = local([lv[0] / r, lv[1] / r, lv[2] / r]);
        if (li[2] <= 0) continue;
        proj(T, li, lo, tmp);
        const s = L.intensity / (r2 * lo[2]);
        acc0 += tmp[0] * s; acc1 += tmp[1] * s; acc2 += tmp[2] * s;
      } else for (const [dir, Ldw] of env) {
        const li = local(dir); if (li[2] <= 0) continue;
        proj(T, li, lo, tmp);
        acc0 += tmp[0] / lo[2] * Ldw[0]; acc1 += tmp[1] / lo[2] * Ldw[1]; acc2 += tmp[2] / lo[2] * Ldw[2];
      }
    }
    const k = row * res + col, n2 = ss * ss;
    rad[3 * k] = acc0 / n2; rad[3 * k + 1] = acc1 / n2; rad[3 * k + 2] = acc2 / n2; cov[k] = hits / n2;
  }
  return { rad, cov };
}
const srgb = x => { x = Math.min(1, Math.max(0, x)); return 255 * (x <= 0.0031308 ? 12.92 * x : 1.055 * Math.pow(x, 1 / 2.4) - 0.055); };
function autoExposure(img) {  // environment light: the 99th luminance percentile to 0.9, as reflecto's previews
  const lum = [];
  for (let k = 0; k < img.cov.length; k++) if (img.cov[k] >= 1)
    lum.push(0.2126 * img.rad[3 * k] + 0.7152 * img.rad[3 * k + 1] + 0.0722 * img.rad[3 * k + 2]);
  lum.sort((a, b) => a - b);
  const p = lum.length ? lum[Math.floor(0.99 * (lum.length - 1))] : 0;
  return p > 0 ? 0.9 / p : 1;
}
function drawSphere(ctx, img, res) {
  const id = ctx.createImageData(res, res), e = state.exposure * (state.mode === "env" ? autoExposure(img) : 1);
  for (let k = 0; k < res * res; k++) for (let ch = 0; ch < 3; ch++)
    id.data[4 * k + ch] = srgb(e * img.rad[3 * k + ch] + (1 - img.cov[k]) * D.background);
  for (let k = 0; k < res * res; k++) id.data[4 * k + 3] = 255;
  ctx.putImageData(id, 0, 0);
}
function fAt(T, th, td, pd, out) {  // f at Rusinkiewicz angles (radians), φ_h = 0
  const d = [Math.sin(td) * Math.cos(pd), Math.sin(td) * Math.sin(pd), Math.cos(td)];
  const i = [Math.cos(th) * d[0] + Math.sin(th) * d[2], d[1], -Math.sin(th) * d[0] + Math.cos(th) * d[2]];
  const h = [Math.sin(th), 0, Math.cos(th)], k = 2 * dot(i, h), o = [k * h[0] - i[0], k * h[1] - i[1], k * h[2] - i[2]];
  if (i[2] <= 1e-6 || o[2] <= 1e-6) { out[0] = out[1] = out[2] = NaN; return out; }
  return fRus(T, th, td, pd, out);
}
const NOT_IN_TABLE = [150, 190, 235];  // the slice's colour where no table node lies above the horizon
function drawSlice(ctx, T, size, readout) {
  const id = ctx.createImageData(size, size), v = [0, 0, 0], pd = state.phid * Math.PI / 180;
  for (let y = 0; y < size; y++) for (let x = 0; x < size; x++) {
    fAt(T, (x + 0.5) / size * HALF_PI, (1 - (y + 0.5) / size) * HALF_PI, pd, v);
    const k = 4 * (y * size + x);
    for (let ch = 0; ch < 3; ch++) id.data[k + ch] = isNaN(v[ch]) ? NOT_IN_TABLE[ch] : 255 * Math.min(1, Math.max(0, (Math.log10(Math.max(v[ch], 1e-4)) + 3) / 6));
    id.data[k + 3] = 255;
  }
  ctx.putImageData(id, 0, 0);
  ctx.canvas.onmousemove = e => {
    const r = ctx.canvas.getBoundingClientRect(), x = (e.clientX - r.left) / r.width, y = (e.clientY - r.top) / r.height;
    fAt(T, x * HALF_PI, (1 - y) * HALF_PI, pd, v);
    readout.textContent = `θ_h ${(x * 90).toFixed(1)}°  θ_d ${((1 - y) * 90).toFixed(1)}°  φ_d ${state.phid}°  f = ` +
      (isNaN(v[0]) ? "at or below the horizon (not in the table)" : `${v[0].toPrecision(4)} ${v[1].toPrecision(4)} ${v[2].toPrecision(4)} sr⁻¹`);
  };
}
function drawPolar(ctx, T, size) {
  const H = ctx.canvas.height;
  ctx.fillStyle = "#fff"; ctx.fillRect(0, 0, size, H);
  const cx = size / 2, cy = H - 18, R = Math.min(size / 2 - 10, H - 50), ti = state.thetai * Math.PI / 180;
  const i = [Math.sin(ti), 0, Math.cos(ti)], v = [0, 0, 0], curves = [[], [], []];
  let vmax = 1e-12;
  for (let k = -89; k <= 89; k++) {
    const to = k * Math.PI / 180, o = [Math.sin(to), 0, Math.cos(to)], r = rusinkiewicz(i, o);
    if (r) fRus(T, r[0], r[1], r[2], v); else v[0] = v[1] = v[2] = 0;
    for (let ch = 0; ch < 3; ch++) { const val = isNaN(v[ch]) ? 0 : v[ch] * o[2]; curves[ch].push([to, val]); vmax = Math.max(vmax, val); }
  }
  ctx.strokeStyle = "#bbb"; ctx.beginPath(); ctx.arc(cx, cy, R, Math.PI, 2 * Math.PI); ctx.stroke();
  ctx.fillStyle = "#444"; ctx.font = "11px sans-serif";
  ctx.fillText("θ_o = −90°", 2, cy + 14); ctx.fillText("+90°", size - 30, cy + 14); ctx.fillText("0°", cx - 6, cy - R - 4);
  ctx.fillText(`f·cos θ_o, max ${vmax.toPrecision(3)}`, 4, 12);
  ["#d33", "#3a3", "#33d"].forEach((col, ch) => {
    ctx.strokeStyle = col; ctx.beginPath();
    curves[ch].forEach(([to, val], k) => { const r = R * val / vmax, x = cx + r * Math.sin(to), y = cy - r * Math.cos(to);
      k ? ctx.lineTo(x, y) : ctx.moveTo(x, y); });
    ctx.stroke();
  });
  ctx.strokeStyle = "#000"; ctx.setLineDash([4, 3]); ctx.beginPath();
  ctx.moveTo(cx, cy); ctx.lineTo(cx + R * Math.sin(ti), cy - R * Math.cos(ti)); ctx.stroke(); ctx.setLineDash([]);
}
const RES = 192, cols = [];
D.brdfs.forEach((b, idx) => {
  const col = document.createElement("div"); col.className = "col";
  col.innerHTML = `<h2></h2><canvas class="sphere" width="${RES}" height="${RES}"></canvas>` +
    `<div>θ_h–θ_d slice: θ_h 0–90° left to right, θ_d 0–90° bottom to top; log f, black 10⁻³, white 10³ sr⁻¹; pale blue: at the horizon, between the table's nodes</div><canvas class="slice" width="180" height="180"></canvas>` +
    `<div class="readout"></div><div>incidence plane at the θ_i above (dashed: the light; R, G, B: f·cos θ_o, linear)</div><canvas class="polar" width="220" height="140"></canvas>`;
  col.querySelector("h2").textContent = b.label;  // a name is text, whatever characters it holds
  document.getElementById("cols").appendChild(col);
  cols.push(col);
});
function update() {
  cols.forEach((col, idx) => {
    const T = TABLES[idx];
    drawSphere(col.querySelector(".sphere").getContext("2d"), renderSphere(T, RES, 1), RES);
    drawSlice(col.querySelector(".slice").getContext("2d"), T, 180, col.querySelector(".readout"));
    drawPolar(col.querySelector(".polar").getContext("2d"), T, 220);
  });
}
function lightFromPointer(e, canvas) {
  const r = canvas.getBoundingClientRect(), x = 2 * (e.clientX - r.left) / r.width - 1, y = 1 - 2 * (e.clientY - r.top) / r.height;
  if (state.mode === "env") { state.envTurn = x * Math.PI; return; }
  const z = Math.sqrt(Math.max(0.05, 1 - x * x - y * y)), dist = Math.hypot(...D.lights[0].position);
  const C = D.camera, dv = norm(C.origin), left = norm(cross(C.up, [-dv[0], -dv[1], -dv[2]])), up2 = cross([-dv[0], -dv[1], -dv[2]], left);
  const w = norm([-x * left[0] + y * up2[0] + z * dv[0], -x * left[1] + y * up2[1] + z * dv[1], -x * left[2] + y * up2[2] + z * dv[2]]);
  state.keyLight = [w[0] * dist, w[1] * dist, w[2] * dist];
}
document.querySelectorAll("canvas.sphere").forEach(cv => {
  let down = false;
  cv.onpointerdown = e => { down = true; lightFromPointer(e, cv); update(); };
  cv.onpointermove = e => { if (down) { lightFromPointer(e, cv); update(); } };
  window.addEventListener("pointerup", () => { down = false; });
});
document.querySelectorAll("input[name=light]").forEach(r => r.onchange = () => { state.mode = r.value; update(); });
document.getElementById("exposure").oninput = e => { state.exposure = Math.pow(2, +e.target.value); update(); };
document.getElementById("phid").oninput = e => { state.phid = +e.target.value; document.getElementById("phid-v").textContent = state.phid + "°"; update(); };
document.getElementById("thetai").oninput = e => { state.thetai = +e.target.value; document.getElementById("thetai-v").textContent = state.thetai + "°"; update(); };
const params = new URLSearchParams(location.hash.slice(1));
if (params.has("light")) {
  const [az, el] = params.get("light").split(",").map(Number), dist = Math.hypot(...D.lights[0].position);
  const a = az * Math.PI / 180, e = el * Math.PI / 180;
  state.keyLight = [dist * Math.cos(e) * Math.sin(a), dist * Math.sin(e), dist * Math.cos(e) * Math.cos(a)];
}
if (params.has("env") && ENV) { state.mode = "env"; document.getElementById("env-radio").checked = true; }
update();
if (params.has("drag")) {  // a pointer press on the first sphere at (x, y), fractions of its size
  const [fx, fy] = params.get("drag").split(",").map(Number), cv = document.querySelector("canvas.sphere");
  const r = cv.getBoundingClientRect();
  cv.dispatchEvent(new PointerEvent("pointerdown", { clientX: r.left + fx * r.width, clientY: r.top + fy * r.height, bubbles: true }));
}
window.reflectoViewer = { state, renderSphere, tables: TABLES, update, fAt };
if (params.has("test")) {
  const res = +params.get("test");
  const out = TABLES.map(T => { const img = renderSphere(T, res, 4); return { radiance: Array.from(img.rad, x => +x.toPrecision(6)), coverage: Array.from(img.cov) }; });
  // the slice's read-out at "θ_h,θ_d,φ_d;…" (degrees) of the first BRDF
  const at = params.has("at") ? params.get("at").split(";").map(t => t.split(",").map(x => +x * Math.PI / 180)) : [];
  const slice = at.map(([th, td, pd]) => Array.from(fAt(TABLES[0], th, td, pd, [0, 0, 0])));
  document.getElementById("test-output").textContent = JSON.stringify({ res, key_light: state.keyLight, spheres: out, slice });
}
</script></body></html>
"""  # noqa: E501 (the page's JavaScript: wrapping it would change the string)
