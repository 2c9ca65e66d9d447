"""``hybridfit view``: one self-contained HTML page showing the fitted hand in 3D, shaded.

The page draws the model's own surface, the rounded cones of
:func:`hybridfit.model.render.build_primitives` (phalanges, palm strands, thenar and web;
radii scaled by the model's bone lengths), each frame's from its fitted joints, lit and
shaded by three.js. three.js (0.185.1 from the npm registry, ``build/three.core.min.js`` and
``build/three.module.min.js`` unchanged, MIT, its licence in ``three/LICENSE`` and its
header kept) is vendored in ``three/`` and written into the page, which therefore loads
nothing: it works offline, from a file, in any browser with WebGL. Why three.js and not
``<model-viewer>`` over the glTF export: the page must name the joint under the pointer,
mark failed frames and move frame by frame, which take a scene graph and a ray caster
(three.js's) rather than a model viewer's fixed controls; and three.js's two modules are
about 750 KB where ``<model-viewer>`` bundles three.js and more.

The view: drag to rotate, the wheel (or the +/- buttons) to zoom, a slider and a play
button to move through the frames; hovering the hand names the joint nearest to the point
under the pointer (one label, with its position), and "names" labels the joints, leaving
out a label that would overlap one nearer the camera. The address's
``#frame=3&yaw=0.5&pitch=-0.3&zoom=1.5&names=1`` sets the starting view. The view starts
as the camera saw the hand (x right, y down), each frame centred on its surface, at a
distance where the hand fills the view. A failed frame shows no hand and says so, and the
failed frames are marked red under the slider. After drawing, the page sets ``data-drawn``
on <body> to the number of surface primitives drawn (0 for a failed frame), ``data-frame``
and ``data-labels`` (the names shown); ``window.hybridfitView.screen(j)`` gives joint j's
position in the window (the tests read these in a headless browser). Names are inert: the
data is JSON with ``<``, ``>`` and ``&`` escaped, shown as text; the title is HTML-escaped,
and a character the file system gave for a byte that is not UTF-8 is written as an escape
(``\\udcff``). A fits file without frames is refused.
"""

from __future__ import annotations

import html
import json
import os
import re
from functools import cache
from importlib.resources import files

import numpy as np

from ..errors import HybridfitError
from ..io import atomic_path
from ..model.render import HandSurface, build_primitives
from .fitted import Fitted

#: the vendored three.js modules (in ``three/``), in the order the page loads them
THREE_FILES = ("three.core.min.js", "three.module.min.js")
#: decimals of the joint coordinates and the surface radii (mm) in the page
DECIMALS = 2


@cache
def three_sources() -> tuple[str, ...]:
    """The texts of :data:`THREE_FILES`."""
    folder = files(__package__).joinpath("three")
    return tuple(folder.joinpath(name).read_text(encoding="utf-8") for name in THREE_FILES)


def page_data(fitted: Fitted) -> dict:
    """What the page draws: joint names, parents, the surface (primitive m's end points are
    ``a[m] @ joints`` and ``b[m] @ joints``, radii ``ra[m]``, ``rb[m]`` mm), per frame the
    model joints (mm) or None for a failed frame, and the frames' indices."""
    result = fitted.result
    Wa, Wb, ra, rb = build_primitives(fitted.model, HandSurface())
    joints = np.round(result.model_joints, DECIMALS)
    return {
        "model": fitted.model_name,
        "source": os.path.basename(fitted.path),
        "names": [str(n) for n in fitted.model.joint_names],
        "parents": np.asarray(fitted.model.parents, dtype=int).tolist(),
        "surface": {"a": np.round(Wa, 6).tolist(), "b": np.round(Wb, 6).tolist(),
                    "ra": np.round(ra, DECIMALS).tolist(), "rb": np.round(rb, DECIMALS).tolist()},
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
    core, module = three_sources()
    parts = {"TITLE": title, "VERSION": html.escape(__version__), "DATA": data, "THREE_CORE": core,
             "THREE_MODULE": module}
    return re.sub(r"__(" + "|".join(parts) + ")__", lambda m: parts[m.group(1)], _PAGE)  # one pass: no part is read again


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
  #track { flex: 1; min-width: 120px; position: relative; }
  #slider { width: 100%; margin: 0; display: block; }
  #marks { position: relative; height: 4px; margin: 0 8px; }
  #marks span { position: absolute; top: 0; height: 4px; min-width: 2px; background: #d62728; }
  #status { min-width: 120px; font-variant-numeric: tabular-nums; }
  button { font: inherit; padding: 2px 9px; }
  #stage { position: relative; flex: 1; min-height: 200px; overflow: hidden; }
  #view { display: block; width: 100%; height: 100%; cursor: grab; touch-action: none; }
  #view.dragging { cursor: grabbing; }
  #axes { position: absolute; left: 0; bottom: 0; width: 84px; height: 84px; pointer-events: none; }
  #names span { position: absolute; pointer-events: none; font-size: 12px; color: #111; white-space: pre;
                background: rgba(255, 255, 255, 0.75); padding: 0 3px; border-radius: 3px; }
  #tip { position: absolute; pointer-events: none; background: rgba(30, 30, 30, 0.88); color: #fff;
         padding: 3px 7px; border-radius: 4px; font-size: 12px; white-space: pre; display: none; }
  #message { position: absolute; left: 0; right: 0; top: 45%; text-align: center; color: #888; font-size: 16px;
             pointer-events: none; }
  #help { position: absolute; right: 10px; bottom: 8px; color: #777; font-size: 12px; }
</style>
</head>
<body>
<header>
  <h1 id="title">__TITLE__</h1>
  <button id="play" title="play / pause">&#9654;</button>
  <div id="track"><input id="slider" type="range" min="0" max="0" value="0" aria-label="frame">
    <div id="marks" title="red: frames that could not be fitted"></div></div>
  <span id="status"></span>
  <label><input id="labels" type="checkbox"> names</label>
  <button id="zoomout" title="zoom out">&minus;</button><button id="zoomin" title="zoom in">+</button>
  <button id="reset" title="the camera's view">reset view</button>
</header>
<div id="stage">
  <canvas id="view"></canvas>
  <canvas id="axes"></canvas>
  <div id="names"></div>
  <div id="tip"></div>
  <div id="message"></div>
  <div id="help">drag: rotate &middot; wheel: zoom &middot; hover: joint names &middot;
    hybridfit __VERSION__ &middot; three.js</div>
</div>
<script type="application/json" id="hand-data">__DATA__</script>
<script type="text/plain" id="three-core">__THREE_CORE__</script>
<script type="text/plain" id="three-module">__THREE_MODULE__</script>
<script>
"use strict";
(function () {
  // three.js as two modules from the page itself: the core as a blob, the module importing it
  const text = id => document.getElementById(id).textContent;
  const blob = source => URL.createObjectURL(new Blob([source], { type: "text/javascript" }));
  const core = blob(text("three-core"));
  const module = blob(text("three-module").split('"./three.core.min.js"').join(JSON.stringify(core)));
  import(module).then(start).catch(err => fail("three.js did not load: " + err));
})();

function fail(why) {
  document.getElementById("message").textContent = why;
  document.body.dataset.drawn = "0";
  document.body.dataset.error = why;
}

function start(THREE) {
  const D = JSON.parse(document.getElementById("hand-data").textContent);
  const stage = document.getElementById("stage"), canvas = document.getElementById("view");
  const slider = document.getElementById("slider"), status = document.getElementById("status");
  const tip = document.getElementById("tip"), labels = document.getElementById("labels");
  const message = document.getElementById("message"), namesLayer = document.getElementById("names");
  const J = D.names.length, F = D.joints.length, S = D.surface, M = S.ra.length;
  let yaw = 0, pitch = 0, zoom = 1, frame = 0, hover = -1, playing = null, drag = null, distance = 1;

  let renderer;
  try {
    renderer = new THREE.WebGLRenderer({ canvas: canvas, antialias: true });
  } catch (err) {
    fail("this browser cannot draw the hand (no WebGL): " + err.message);
    return;
  }
  renderer.setClearColor(0xfafafa);
  const scene = new THREE.Scene(), camera = new THREE.PerspectiveCamera(30, 1, 1, 1e5);
  camera.up.set(0, -1, 0);  // the camera's axes: x right, y down, looking along +z
  scene.add(new THREE.HemisphereLight(0xffffff, 0x5a4a40, 1.0));
  const light = new THREE.DirectionalLight(0xffffff, 2.6);
  light.position.set(-0.6, 1, 1.5);  // in the camera's frame: above left of it, moving with it
  camera.add(light);
  scene.add(camera);
  const hand = new THREE.Group();  // the hand about its centre, turned by yaw and pitch
  scene.add(hand);
  const skin = new THREE.MeshStandardMaterial({ color: 0xe8b896, roughness: 0.6, metalness: 0 });
  const meshes = [];
  for (let m = 0; m < M; m++) { meshes.push(new THREE.Mesh(new THREE.BufferGeometry(), skin)); hand.add(meshes[m]); }
  const marker = new THREE.Mesh(new THREE.SphereGeometry(1, 16, 8),
                                new THREE.MeshBasicMaterial({ color: 0x202020, depthTest: false }));
  marker.renderOrder = 1;
  hand.add(marker);
  const spans = D.names.map(n => { const s = document.createElement("span"); s.textContent = n;
                                   namesLayer.appendChild(s); return s; });

  // per frame: the primitives' end points (a @ joints, b @ joints) and the centre of their bounding box
  const dot = (w, p) => { const v = [0, 0, 0]; w.forEach((c, j) => { if (c) { v[0] += c * p[j][0];
                          v[1] += c * p[j][1]; v[2] += c * p[j][2]; } }); return v; };
  const ends = D.joints.map(p => p && { a: S.a.map(w => dot(w, p)), b: S.b.map(w => dot(w, p)) });
  const centres = ends.map(e => {
    if (!e) return null;
    const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
    for (let m = 0; m < M; m++) for (const [q, r] of [[e.a[m], S.ra[m]], [e.b[m], S.rb[m]]])
      for (let k = 0; k < 3; k++) { lo[k] = Math.min(lo[k], q[k] - r); hi[k] = Math.max(hi[k], q[k] + r); }
    return lo.map((v, k) => (v + hi[k]) / 2);
  });

  const firstFitted = D.joints.findIndex(p => p);
  frame = firstFitted < 0 ? 0 : firstFitted;
  // the starting view from the address's #fragment, e.g. page.html#frame=3&yaw=0.5&pitch=-0.3&zoom=1.5&names=1
  const start = new URLSearchParams(location.hash.slice(1));
  if (start.has("frame")) frame = Math.max(0, Math.min(F - 1, Math.round(Number(start.get("frame"))) || 0));
  yaw = Number(start.get("yaw")) || 0;
  pitch = Number(start.get("pitch")) || 0;
  zoom = Number(start.get("zoom")) || 1;
  labels.checked = start.get("names") === "1";
  slider.max = String(Math.max(F - 1, 0));
  slider.value = String(frame);
  markFailed();

  function markFailed() {  // a red mark under the slider for each run of failed frames
    const marks = document.getElementById("marks");
    for (let f = 0; f < F; f++) {
      if (D.joints[f] || (f > 0 && !D.joints[f - 1])) continue;
      let g = f; while (g + 1 < F && !D.joints[g + 1]) g++;
      const s = document.createElement("span"), n = Math.max(F - 1, 1);
      s.style.left = (100 * f / n) + "%";
      s.style.width = "calc(" + (100 * (g - f) / n) + "% + 2px)";
      s.style.marginLeft = "-1px";
      marks.appendChild(s);
    }
  }

  // a rounded cone from a to b (radii r1, r2): a lathe of two sphere caps joined by their common tangent
  function roundedCone(a, b, r1, r2) {
    const axis = new THREE.Vector3(b[0] - a[0], b[1] - a[1], b[2] - a[2]), L = axis.length();
    const s = Math.max(-1, Math.min(1, L > 1e-9 ? (r1 - r2) / L : (r1 > r2 ? 1 : -1))), t = Math.asin(s);
    const profile = [], steps = 8;
    for (let i = 0; i <= steps; i++) { const u = -Math.PI / 2 + (t + Math.PI / 2) * i / steps;
      profile.push(new THREE.Vector2(r1 * Math.cos(u), r1 * Math.sin(u))); }
    for (let i = 0; i <= steps; i++) { const u = t + (Math.PI / 2 - t) * i / steps;
      profile.push(new THREE.Vector2(r2 * Math.cos(u), L + r2 * Math.sin(u))); }
    profile[0].x = profile[profile.length - 1].x = 0;
    const geometry = new THREE.LatheGeometry(profile, 28);
    const turn = new THREE.Quaternion().setFromUnitVectors(new THREE.Vector3(0, 1, 0),
                                                           L > 1e-9 ? axis.divideScalar(L) : new THREE.Vector3(0, 1, 0));
    geometry.applyQuaternion(turn);
    geometry.translate(a[0], a[1], a[2]);
    return geometry;
  }

  let built = -1;
  function build() {  // the current frame's surface, about its centre
    if (built === frame) return;
    built = frame;
    const e = ends[frame];
    if (!e) return;
    const c = centres[frame], rel = q => [q[0] - c[0], q[1] - c[1], q[2] - c[2]];
    for (let m = 0; m < M; m++) {
      meshes[m].geometry.dispose();
      meshes[m].geometry = roundedCone(rel(e.a[m]), rel(e.b[m]), S.ra[m], S.rb[m]);
    }
  }

  const local = j => { const q = D.joints[frame][j], c = centres[frame];
                       return new THREE.Vector3(q[0] - c[0], q[1] - c[1], q[2] - c[2]); };

  function turn() { hand.rotation.set(pitch, yaw, 0, "XYZ"); hand.updateMatrixWorld(true); }

  // the camera's distance at which every frame's surface, turned as now, fits in the view
  function fit() {
    const w = stage.clientWidth, h = stage.clientHeight, ty = Math.tan(camera.fov * Math.PI / 360) * 0.95;
    const tx = ty * w / h, R = new THREE.Matrix4().makeRotationFromEuler(new THREE.Euler(pitch, yaw, 0, "XYZ"));
    const v = new THREE.Vector3();
    distance = 1;
    ends.forEach((e, f) => {
      if (!e) return;
      const c = centres[f];
      for (let m = 0; m < M; m++) for (const [q, r] of [[e.a[m], S.ra[m]], [e.b[m], S.rb[m]]]) {
        v.set(q[0] - c[0], q[1] - c[1], q[2] - c[2]).applyMatrix4(R);
        const near = -v.z + r;  // towards the camera, which is at z = -distance
        distance = Math.max(distance, (Math.abs(v.x) + r) / tx + near, (Math.abs(v.y) + r) / ty + near);
      }
    });
  }

  function screen(j) {  // joint j of the current frame in CSS pixels of the stage, or null
    if (!D.joints[frame]) return null;
    const p = hand.localToWorld(local(j)).project(camera);
    return [(p.x + 1) / 2 * stage.clientWidth, (1 - p.y) / 2 * stage.clientHeight, p.z];
  }

  function draw() {
    const w = stage.clientWidth, h = stage.clientHeight;
    renderer.setPixelRatio(window.devicePixelRatio || 1);
    renderer.setSize(w, h, false);
    camera.aspect = w / Math.max(h, 1);
    camera.zoom = zoom;
    camera.position.set(0, 0, -distance);
    camera.lookAt(0, 0, 0);
    camera.updateProjectionMatrix();
    turn();
    const p = D.joints[frame];
    status.textContent = "frame " + D.frames[frame] + " (" + (frame + 1) + " of " + F + ")" + (p ? "" : ": not fitted");
    message.textContent = p ? "" : "frame " + D.frames[frame] + " could not be fitted";
    hand.visible = !!p;
    if (p) build();
    marker.visible = !!p && hover >= 0;
    if (marker.visible) { marker.position.copy(local(hover)); marker.scale.setScalar(2); }
    renderer.render(scene, camera);
    axes();
    names();
    document.body.dataset.drawn = String(p ? M : 0);
    document.body.dataset.frame = String(frame);
  }

  function names() {  // every joint's name, nearest the camera first, leaving out any that would overlap one shown
    let shown = 0;
    const placed = [], order = [];
    if (labels.checked && D.joints[frame]) for (let j = 0; j < J; j++) order.push([screen(j), j]);
    order.sort((x, y) => x[0][2] - y[0][2]);
    spans.forEach(s => { s.style.display = "none"; });
    for (const [q, j] of order) {
      const s = spans[j];
      s.style.left = (q[0] + 6) + "px"; s.style.top = (q[1] - 18) + "px"; s.style.display = "block";
      const r = [q[0] + 6, q[1] - 18, q[0] + 6 + s.offsetWidth, q[1] - 18 + s.offsetHeight];
      if (placed.some(o => r[0] < o[2] && o[0] < r[2] && r[1] < o[3] && o[1] < r[3])) { s.style.display = "none"; continue; }
      placed.push(r);
      shown++;
    }
    document.body.dataset.labels = String(shown);
  }

  function axes() {  // the camera's axes, bottom left
    const a = document.getElementById("axes"), dpr = window.devicePixelRatio || 1, g = a.getContext("2d");
    a.width = 84 * dpr; a.height = 84 * dpr;
    g.setTransform(dpr, 0, 0, dpr, 0, 0);
    const R = new THREE.Matrix4().makeRotationFromEuler(new THREE.Euler(pitch, yaw, 0, "XYZ"));
    const names = ["x", "y", "z"], colours = ["#c0392b", "#27ae60", "#2c6fbb"];
    g.lineWidth = 2;
    g.font = "11px system-ui, sans-serif";
    for (let k = 0; k < 3; k++) {
      const v = new THREE.Vector3(k === 0 ? 1 : 0, k === 1 ? 1 : 0, k === 2 ? 1 : 0).applyMatrix4(R);
      const end = [42 + 26 * v.x, 42 + 26 * v.y];
      g.strokeStyle = g.fillStyle = colours[k];
      g.beginPath(); g.moveTo(42, 42); g.lineTo(end[0], end[1]); g.stroke();
      g.fillText(names[k], end[0] + 3, end[1] + 3);
    }
  }

  const ray = new THREE.Raycaster(), pointer = new THREE.Vector2();
  function pick(x, y) {  // the joint nearest to the surface point under (x, y), or -1
    if (!D.joints[frame]) return -1;
    pointer.set(x / stage.clientWidth * 2 - 1, 1 - y / stage.clientHeight * 2);
    ray.setFromCamera(pointer, camera);
    const hit = ray.intersectObjects(meshes, false)[0];
    if (!hit) return -1;
    const q = hand.worldToLocal(hit.point.clone());
    let best = -1, bestD = Infinity;
    for (let j = 0; j < J; j++) { const d = local(j).distanceToSquared(q); if (d < bestD) { bestD = d; best = j; } }
    return best;
  }

  function unhover() { hover = -1; tip.style.display = "none"; }

  canvas.addEventListener("pointerdown", e => {
    drag = [e.clientX, e.clientY]; canvas.setPointerCapture(e.pointerId); canvas.classList.add("dragging");
  });
  canvas.addEventListener("pointerup", () => { drag = null; canvas.classList.remove("dragging"); });
  canvas.addEventListener("pointermove", e => {
    const r = canvas.getBoundingClientRect(), x = e.clientX - r.left, y = e.clientY - r.top;
    if (drag) {
      yaw += (e.clientX - drag[0]) * 0.01;
      pitch = Math.max(-Math.PI / 2, Math.min(Math.PI / 2, pitch - (e.clientY - drag[1]) * 0.01));
      drag = [e.clientX, e.clientY];
      turn();
    }
    hover = pick(x, y);
    if (hover >= 0) {
      const q = D.joints[frame][hover];
      tip.textContent = D.names[hover] + "  (" + q.map(v => v.toFixed(1)).join(", ") + ") mm";
      tip.style.display = "block";  // beside the pointer, inside the view
      tip.style.left = Math.max(0, x + 14 + tip.offsetWidth > stage.clientWidth ? x - 8 - tip.offsetWidth : x + 14) + "px";
      tip.style.top = Math.min(y + 12, stage.clientHeight - tip.offsetHeight) + "px";
    } else {
      unhover();
    }
    draw();
  });
  canvas.addEventListener("pointerleave", () => { unhover(); draw(); });
  canvas.addEventListener("wheel", e => { e.preventDefault(); zoom *= Math.exp(-e.deltaY * 0.001); draw(); },
                          { passive: false });
  slider.addEventListener("input", () => { frame = Number(slider.value); unhover(); draw(); });
  labels.addEventListener("change", draw);
  document.getElementById("zoomin").addEventListener("click", () => { zoom *= 1.25; draw(); });
  document.getElementById("zoomout").addEventListener("click", () => { zoom /= 1.25; draw(); });
  document.getElementById("reset").addEventListener("click", () => { yaw = pitch = 0; zoom = 1; turn(); fit(); draw(); });
  document.getElementById("play").addEventListener("click", e => {
    const button = e.currentTarget;
    if (playing) { clearInterval(playing); playing = null; button.innerHTML = "&#9654;"; return; }
    button.innerHTML = "&#10074;&#10074;";
    playing = setInterval(() => { frame = (frame + 1) % F; slider.value = String(frame); unhover(); draw(); }, 1000 / 30);
  });
  window.addEventListener("resize", () => { fit(); draw(); });
  window.hybridfitView = { screen: j => {  // in the window's CSS pixels
    const q = screen(j), r = stage.getBoundingClientRect(); return q && [r.left + q[0], r.top + q[1]]; } };
  fit();
  draw();
}
</script>
</body>
</html>
"""
