"""``hybridfit view``: one self-contained HTML page showing the fitted hand in 3D.

The page holds its data (every frame's model joints, the joint names and the skeleton) and
its script inline, and loads nothing: it works offline, from a file, in any current
browser. The drawing is a <canvas> 2D context with a perspective projection written here
(no WebGL, no library): drag to rotate, the wheel (or the +/- buttons) to zoom, a slider
and a play button to move through the frames, the joints' names and positions on hover
(all names with "names"); the address's ``#frame=3&yaw=0.5&pitch=-0.3&zoom=1.5&names=1``
sets the starting view. Bones are coloured by the chain they belong to (one colour per
child of the root: per finger for a hand), in :data:`BONE_COLOURS`. The view starts as the
camera saw the hand (x right, y down), each frame centred on its joints. Failed frames show
no hand and say so. After drawing, the page sets ``data-drawn`` on <body> to the number of
bones drawn (the tests read it in a headless browser). Names are inert: the data is JSON
with ``<``, ``>`` and ``&`` escaped, drawn as text; the title is HTML-escaped, and a
character the file system gave for a byte that is not UTF-8 is written as an escape
(``\\udcff``). A fits file without frames is refused.
"""

from __future__ import annotations

import html
import json
import os

import numpy as np

from ..errors import HybridfitError
from ..io import atomic_path
from .fitted import Fitted

#: bone colours, one per chain from the root (cycled), as #rrggbb
BONE_COLOURS = ("#d62728", "#1f77b4", "#2ca02c", "#ff7f0e", "#9467bd", "#8c564b", "#e377c2", "#17becf")
#: decimals of the joint coordinates (mm) in the page
DECIMALS = 2


def _chains(parents: np.ndarray) -> list[int]:
    """(J,) each joint's chain: the index among the root's children of the one it descends from (0 for the root)."""
    roots = [j for j, p in enumerate(parents) if p < 0]
    first = {c: i for i, c in enumerate(j for j, p in enumerate(parents) if p in roots)}
    chain = []
    for j in range(len(parents)):
        k = j
        while parents[k] >= 0 and k not in first:
            k = int(parents[k])
        chain.append(first.get(k, 0))
    return chain


def page_data(fitted: Fitted) -> dict:
    """What the page draws: joint names, parents, chains, per frame the model joints (mm) or
    None for a failed frame, and the frames' indices."""
    result = fitted.result
    parents = np.asarray(fitted.model.parents, dtype=int)
    joints = np.round(result.model_joints, DECIMALS)
    return {
        "model": fitted.model_name,
        "source": os.path.basename(fitted.path),
        "names": [str(n) for n in fitted.model.joint_names],
        "parents": parents.tolist(),
        "chains": _chains(parents),
        "colours": list(BONE_COLOURS),
        "frames": [int(f) for f in fitted.frames],
        "joints": [None if result.failed[f] else joints[f].tolist() for f in range(len(joints))],
    }


def view_page(fitted: Fitted) -> str:
    """The HTML page (see the module docstring)."""
    from .. import __version__

    if not len(fitted.result.params):
        raise HybridfitError(f"{fitted.path}: no frames (an empty fit): nothing to view")
    data = json.dumps(page_data(fitted), separators=(",", ":"), allow_nan=False)
    data = data.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")
    title = html.escape(f"{os.path.basename(fitted.path)} \u00b7 {fitted.model_name}")
    return _PAGE.replace("__TITLE__", title).replace("__VERSION__", html.escape(__version__)).replace("__DATA__", data)


def write_view(path: str | os.PathLike, fitted: Fitted) -> None:
    """Write :func:`view_page` (atomically: an existing file is replaced only by a complete one)."""
    text = view_page(fitted)
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8", errors="backslashreplace")  # a file name's lone surrogates


_PAGE = r"""<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>__TITLE__</title>
<style>
  html, body { margin: 0; height: 100%; background: #fafafa; color: #222;
               font: 14px system-ui, -apple-system, "Segoe UI", sans-serif; }
  body { display: flex; flex-direction: column; }
  header { padding: 6px 10px; display: flex; gap: 8px; align-items: center; flex-wrap: wrap;
           border-bottom: 1px solid #ddd; background: #fff; }
  header h1 { font-size: 15px; margin: 0 8px 0 0; font-weight: 600; }
  #slider { flex: 1; min-width: 120px; }
  #status { min-width: 120px; font-variant-numeric: tabular-nums; }
  button { font: inherit; padding: 2px 9px; }
  #stage { position: relative; flex: 1; min-height: 200px; }
  canvas { display: block; width: 100%; height: 100%; cursor: grab; touch-action: none; }
  canvas.dragging { cursor: grabbing; }
  #tip { position: absolute; pointer-events: none; background: rgba(30, 30, 30, 0.88); color: #fff;
         padding: 3px 7px; border-radius: 4px; font-size: 12px; white-space: nowrap; display: none; }
  #help { position: absolute; right: 10px; bottom: 8px; color: #777; font-size: 12px; }
</style>
</head>
<body>
<header>
  <h1 id="title">__TITLE__</h1>
  <button id="play" title="play / pause">&#9654;</button>
  <input id="slider" type="range" min="0" max="0" value="0" aria-label="frame">
  <span id="status"></span>
  <label><input id="labels" type="checkbox"> names</label>
  <button id="zoomout" title="zoom out">&minus;</button><button id="zoomin" title="zoom in">+</button>
  <button id="reset" title="the camera's view">reset view</button>
</header>
<div id="stage">
  <canvas id="view"></canvas>
  <div id="tip"></div>
  <div id="help">drag: rotate &middot; wheel: zoom &middot; hover: joint names &middot; hybridfit __VERSION__</div>
</div>
<script type="application/json" id="hand-data">__DATA__</script>
<script>
"use strict";
(function () {
  const D = JSON.parse(document.getElementById("hand-data").textContent);
  const canvas = document.getElementById("view"), ctx = canvas.getContext("2d");
  const slider = document.getElementById("slider"), status = document.getElementById("status");
  const tip = document.getElementById("tip"), labels = document.getElementById("labels");
  const J = D.names.length, F = D.joints.length;
  let yaw = 0, pitch = 0, zoom = 1, frame = 0, hover = -1, playing = null, drag = null;
  let projected = [];

  // one scale for every frame: the largest distance of a joint from its frame's centre
  let radius = 1;
  const centre = p => { const c = [0, 0, 0]; p.forEach(q => { c[0] += q[0]; c[1] += q[1]; c[2] += q[2]; });
                        return c.map(v => v / p.length); };
  D.joints.forEach(p => { if (!p) return; const c = centre(p);
    p.forEach(q => { radius = Math.max(radius, Math.hypot(q[0] - c[0], q[1] - c[1], q[2] - c[2])); }); });
  const firstFitted = D.joints.findIndex(p => p);
  frame = firstFitted < 0 ? 0 : firstFitted;
  // the starting view from the address's #fragment, e.g. page.html#frame=3&yaw=0.5&pitch=-0.3&zoom=1.5&names=1
  const start = new URLSearchParams(location.hash.slice(1));
  if (start.has("frame")) frame = Math.max(0, Math.min(F - 1, Number(start.get("frame")) || 0));
  yaw = Number(start.get("yaw")) || 0;
  pitch = Number(start.get("pitch")) || 0;
  zoom = Number(start.get("zoom")) || 1;
  labels.checked = start.get("names") === "1";
  slider.max = String(Math.max(F - 1, 0));
  slider.value = String(frame);

  function size() {
    const r = canvas.getBoundingClientRect(), dpr = window.devicePixelRatio || 1;
    canvas.width = Math.max(1, Math.round(r.width * dpr));
    canvas.height = Math.max(1, Math.round(r.height * dpr));
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    return [r.width, r.height];
  }

  // camera coordinates (x right, y down, z away) rotated by yaw (about y) then pitch (about x)
  function rotate(v) {
    const cy = Math.cos(yaw), sy = Math.sin(yaw), cp = Math.cos(pitch), sp = Math.sin(pitch);
    const x = cy * v[0] + sy * v[2], z = -sy * v[0] + cy * v[2];
    return [x, cp * v[1] - sp * z, sp * v[1] + cp * z];
  }

  function draw() {
    const [w, h] = size();
    ctx.clearRect(0, 0, w, h);
    const p = D.joints[frame];
    status.textContent = "frame " + D.frames[frame] + " (" + (frame + 1) + " of " + F + ")" + (p ? "" : ": not fitted");
    let bones = 0;
    projected = [];
    if (p) {
      const c = centre(p), scale = 0.42 * Math.min(w, h) / radius * zoom, dist = 4 * radius;
      projected = p.map(q => {
        const r = rotate([q[0] - c[0], q[1] - c[1], q[2] - c[2]]), f = dist / (dist + r[2]);
        return [w / 2 + scale * f * r[0], h / 2 + scale * f * r[1], r[2]];
      });
      const items = [];
      for (let j = 0; j < J; j++) {
        const par = D.parents[j];
        if (par >= 0) items.push({ depth: (projected[j][2] + projected[par][2]) / 2, bone: [par, j] });
        items.push({ depth: projected[j][2] - 0.01, joint: j });
      }
      items.sort((a, b) => b.depth - a.depth);  // far first: near bones cover far ones
      ctx.lineCap = "round";
      for (const it of items) {
        if (it.bone) {
          const [a, b] = it.bone, colour = D.colours[D.chains[b] % D.colours.length];
          ctx.strokeStyle = colour;
          ctx.lineWidth = 7;
          ctx.beginPath(); ctx.moveTo(projected[a][0], projected[a][1]); ctx.lineTo(projected[b][0], projected[b][1]);
          ctx.stroke();
          bones++;
        } else {
          const j = it.joint, q = projected[j];
          ctx.fillStyle = j === hover ? "#000" : "#444";
          ctx.beginPath(); ctx.arc(q[0], q[1], j === hover ? 6.5 : 4.5, 0, 2 * Math.PI); ctx.fill();
        }
      }
      ctx.font = "12px system-ui, sans-serif";
      ctx.fillStyle = "#111";
      for (let j = 0; j < J; j++) {
        if (labels.checked || j === hover) ctx.fillText(D.names[j], projected[j][0] + 8, projected[j][1] - 6);
      }
    } else {
      ctx.fillStyle = "#888";
      ctx.font = "16px system-ui, sans-serif";
      ctx.textAlign = "center";
      ctx.fillText("frame " + D.frames[frame] + " could not be fitted", w / 2, h / 2);
      ctx.textAlign = "start";
    }
    axes(h);
    document.body.dataset.drawn = String(bones);
    document.body.dataset.frame = String(frame);
  }

  function axes(h) {  // the camera's axes, bottom left
    const o = [42, h - 42], names = ["x", "y", "z"], colours = ["#c0392b", "#27ae60", "#2c6fbb"];
    ctx.lineWidth = 2;
    ctx.font = "11px system-ui, sans-serif";
    for (let a = 0; a < 3; a++) {
      const v = [0, 0, 0]; v[a] = 1;
      const r = rotate(v), end = [o[0] + 26 * r[0], o[1] + 26 * r[1]];
      ctx.strokeStyle = ctx.fillStyle = colours[a];
      ctx.beginPath(); ctx.moveTo(o[0], o[1]); ctx.lineTo(end[0], end[1]); ctx.stroke();
      ctx.fillText(names[a], end[0] + 3, end[1] + 3);
    }
  }

  function nearest(x, y) {
    let best = -1, bestD = 12;
    projected.forEach((q, j) => { const d = Math.hypot(q[0] - x, q[1] - y); if (d < bestD) { bestD = d; best = j; } });
    return best;
  }

  canvas.addEventListener("pointerdown", e => {
    drag = [e.clientX, e.clientY]; canvas.setPointerCapture(e.pointerId); canvas.classList.add("dragging");
  });
  canvas.addEventListener("pointerup", e => { drag = null; canvas.classList.remove("dragging"); });
  canvas.addEventListener("pointermove", e => {
    const r = canvas.getBoundingClientRect(), x = e.clientX - r.left, y = e.clientY - r.top;
    if (drag) {
      yaw += (e.clientX - drag[0]) * 0.01;
      pitch = Math.max(-Math.PI / 2, Math.min(Math.PI / 2, pitch - (e.clientY - drag[1]) * 0.01));
      drag = [e.clientX, e.clientY];
    }
    hover = nearest(x, y);
    if (hover >= 0) {
      const q = D.joints[frame][hover];
      tip.textContent = D.names[hover] + "  (" + q.map(v => v.toFixed(1)).join(", ") + ") mm";
      tip.style.left = (x + 14) + "px"; tip.style.top = (y + 12) + "px"; tip.style.display = "block";
    } else {
      tip.style.display = "none";
    }
    draw();
  });
  canvas.addEventListener("pointerleave", () => { hover = -1; tip.style.display = "none"; draw(); });
  canvas.addEventListener("wheel", e => { e.preventDefault(); zoom *= Math.exp(-e.deltaY * 0.001); draw(); },
                          { passive: false });
  slider.addEventListener("input", () => { frame = Number(slider.value); hover = -1; tip.style.display = "none"; draw(); });
  labels.addEventListener("change", draw);
  document.getElementById("zoomin").addEventListener("click", () => { zoom *= 1.25; draw(); });
  document.getElementById("zoomout").addEventListener("click", () => { zoom /= 1.25; draw(); });
  document.getElementById("reset").addEventListener("click", () => { yaw = pitch = 0; zoom = 1; draw(); });
  document.getElementById("play").addEventListener("click", e => {
    if (playing) { clearInterval(playing); playing = null; e.target.innerHTML = "&#9654;"; return; }
    e.target.innerHTML = "&#10074;&#10074;";
    playing = setInterval(() => { frame = (frame + 1) % F; slider.value = String(frame); draw(); }, 1000 / 30);
  });
  window.addEventListener("resize", draw);
  draw();
})();
</script>
</body>
</html>
"""
