// photonmap view: the page. Frames arrive on the WebSocket /api/stream (a JSON message, then
// the image); every change goes to POST /api/update, at most one request in flight, the rest
// merged into one pending update (the newest value of each key wins). Drags send preview
// updates (a low-resolution image); releasing the mouse sends the final full-resolution one.
"use strict";

const $ = (id) => document.getElementById(id);
const viewer = (window.viewer = { state: null, meta: null, frames: 0, imageUrl: null, errors: 0 });
// the server's token, from the URL it printed (the page's cookie carries it too)
const TOKEN = new URLSearchParams(location.search).get("token") || "";
const AUTH = TOKEN ? { "X-Photonmap-Token": TOKEN } : {};

// ------------------------------------------------------------------ vectors and the camera
const sub = (a, b) => a.map((v, i) => v - b[i]);
const add = (a, b) => a.map((v, i) => v + b[i]);
const mul = (a, s) => a.map((v) => v * s);
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const norm = (a) => mul(a, 1 / Math.hypot(...a));

// Mitsuba's perspective camera (look_at with +y up, horizontal fov): image x runs along
// cross(forward, up), image y down along -cross(right, forward).
function basis(cam) {
  const f = norm(sub(cam.target, cam.origin));
  const r = norm(cross(f, [0, 1, 0]));
  return { f, r, u: cross(r, f), t: Math.tan((cam.fov * Math.PI) / 360), aspect: cam.height / cam.width };
}
function project(cam, p) { // world point -> [x, y] in [0, 1]² of the image, or null behind
  const b = basis(cam), d = sub(p, cam.origin), z = dot(d, b.f);
  if (z <= 1e-6) return null;
  return [0.5 + (0.5 * dot(d, b.r)) / (z * b.t), 0.5 - (0.5 * dot(d, b.u)) / (z * b.t * b.aspect)];
}
function unproject(cam, x, y, depth) { // image point in [0, 1]² at distance `depth` along f
  const b = basis(cam);
  const dir = add(b.f, add(mul(b.r, (2 * x - 1) * b.t), mul(b.u, (1 - 2 * y) * b.t * b.aspect)));
  return add(cam.origin, mul(dir, depth));
}

// ------------------------------------------------------------------ talking to the server
let pending = null, inFlight = false;
viewer.busy = () => pending !== null || inFlight; // an update not yet answered
function mergeUpdate(a, b) {
  const out = { ...a };
  for (const [k, v] of Object.entries(b)) {
    if (k === "lights") {
      out.lights = { ...(a.lights || {}) };
      for (const [i, l] of Object.entries(v)) out.lights[i] = { ...(out.lights[i] || {}), ...l };
    } else if (k === "materials") {
      out.materials = { ...(a.materials || {}) };
      for (const [n, m] of Object.entries(v)) out.materials[n] = { ...(out.materials[n] || {}), ...m };
    } else if (v && typeof v === "object" && !Array.isArray(v)) {
      out[k] = { ...(a[k] || {}), ...v };
    } else out[k] = v;
  }
  return out;
}
function send(update) {
  pending = mergeUpdate(pending || {}, update);
  if (!inFlight) flush();
}
async function flush() {
  if (!pending) { inFlight = false; return; }
  const body = pending;
  pending = null;
  inFlight = true;
  try {
    const res = await fetch("/api/update", {
      method: "POST", headers: { "Content-Type": "application/json", ...AUTH }, body: JSON.stringify(body),
    });
    const reply = await res.json();
    if (res.ok) {
      viewer.version = reply.version;
      showError(null);
      if (!pending && !drag) { viewer.state = reply.state; fillControls(); }
    } else {
      showError(reply.detail || res.statusText);
      await loadState(); // the server kept its state: show it again
    }
  } catch (e) {
    showError(String(e));
  }
  flush();
}
async function post(path, body) {
  const res = await fetch(path, {
    method: "POST", headers: { "Content-Type": "application/json", ...AUTH }, body: JSON.stringify(body || {}),
  });
  const reply = await res.json();
  if (!res.ok) showError(reply.detail || res.statusText); else showError(null);
  return reply;
}
function showError(text) {
  const box = $("error");
  box.hidden = !text;
  box.textContent = text ? `error: ${text}` : "";
  if (text) viewer.errors += 1;
}
async function loadState() {
  viewer.state = await (await fetch("/api/state", { headers: AUTH })).json();
  fillControls();
}

function connect() {
  const query = TOKEN ? `?token=${encodeURIComponent(TOKEN)}` : "";
  const ws = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/api/stream${query}`);
  ws.binaryType = "blob";
  let meta = null;
  ws.onmessage = (event) => {
    if (typeof event.data === "string") {
      const msg = JSON.parse(event.data);
      if (msg.type === "error") { showError(msg.message); loadState(); } else meta = msg;
      return;
    }
    const blob = event.data.slice(0, event.data.size, meta.mime);
    const url = URL.createObjectURL(blob);
    const img = $("frame");
    img.onload = () => {
      if (viewer.imageUrl) URL.revokeObjectURL(viewer.imageUrl);
      viewer.imageUrl = url;
      viewer.meta = meta;
      viewer.frames += 1;
      drawOverlay();
      showStats(meta);
      if (!drag && !viewer.busy() && meta.version > (viewer.version || 0)) {
        viewer.version = meta.version; // changed by another page or a script: show its values
        loadState();
      }
      if (playing && !meta.preview) nextVolumeFrame();
    };
    img.src = url;
  };
  ws.onclose = () => setTimeout(connect, 1000);
}

// ------------------------------------------------------------------ controls
const fmt = (v) => (Math.abs(v) >= 100 ? v.toFixed(0) : Number(v.toPrecision(4)).toString());
const mean = (a) => (Array.isArray(a) ? (a[0] + a[1] + a[2]) / 3 : a);
const hex = (c) => "#" + c.map((v) => Math.round(255 * Math.min(1, Math.max(0, v))).toString(16).padStart(2, "0")).join("");
const unhex = (h) => [1, 3, 5].map((i) => parseInt(h.slice(i, i + 2), 16) / 255);
const CHOICES = { emission: ["uniform", "adaptive"] };
let intensity0 = null;

function fillControls() {
  const s = viewer.state;
  $("title").textContent = `${s.scene} · ${s.method}`;
  const li = $("light-index");
  if (li.options.length !== s.lights.length) {
    li.innerHTML = s.lights.map((l, i) => `<option value="${i}">${i}: ${l.kind}</option>`).join("");
  }
  const light = s.lights[+li.value || 0];
  $("light-box").hidden = !light;
  if (light) {
    $("light-color").value = hex(light.color);
    if (intensity0 === null) intensity0 = Math.max(light.intensity, 1e-3);
    $("light-intensity").value = fmt(light.intensity);
    $("light-intensity-range").value = Math.log10(Math.max(light.intensity, 1e-9) / intensity0);
  }
  const names = Object.keys(s.materials);
  const mn = $("material-name");
  if (mn.options.length !== names.length) mn.innerHTML = names.map((n) => `<option>${n}</option>`).join("");
  $("material-box").hidden = !names.length;
  const mat = s.materials[mn.value];
  for (const key of ["ior", "sigma_s", "sigma_a"]) {
    const row = document.querySelector(`.row[data-key=${key}]`);
    row.hidden = !mat || !(key in mat);
    if (mat && key in mat) {
      const v = mean(mat[key]);
      $(`mat-${key}`).value = fmt(v);
      const range = $(`mat-${key}-range`);
      if (key !== "ior" && v * 2 > +range.max) range.max = String(4 * v);
      range.value = v;
    }
  }
  const params = $("params");
  if (!params.children.length) {
    params.innerHTML = Object.entries(s.params).map(([k, v]) => {
      const input = CHOICES[k]
        ? `<select id="param-${k}">${CHOICES[k].map((c) => `<option>${c}</option>`).join("")}</select>`
        : `<input type="number" id="param-${k}" step="any">`;
      return `<label>${k} ${input}</label>`;
    }).join("");
    for (const k of Object.keys(s.params)) {
      $(`param-${k}`).addEventListener("change", (e) => {
        const raw = e.target.value;
        const value = CHOICES[k] ? raw : (raw.trim() === "" || isNaN(Number(raw)) ? raw : Number(raw));
        send({ params: { [k]: value } });
      });
    }
  }
  for (const [k, v] of Object.entries(s.params)) $(`param-${k}`).value = v;
  const volume = "brush_fields" in s;
  $("volume-box").hidden = !volume;
  $("paint-mode").hidden = !volume;
  if (volume && s.frames > 0) {
    $("sequence").hidden = false;
    $("frame-index").max = s.frames - 1;
    $("frame-index").value = s.volume.frame;
    $("frame-label").textContent = s.volume.frame < 0 ? "scene" : `frame ${s.volume.frame}`;
  }
  drawOverlay();
}

function numberOrText(raw) {
  return raw.trim() === "" || isNaN(Number(raw)) ? raw : Number(raw);
}
function lightUpdate(changes) {
  return { lights: { [$("light-index").value || 0]: changes } };
}
function materialValue(key, v) {
  const mat = viewer.state.materials[$("material-name").value];
  if (key === "ior" || typeof v !== "number") return v;
  const m = mean(mat[key]);
  return m > 0 ? mat[key].map((c) => (c * v) / m) : v; // keep the hue
}
function materialUpdate(key, v, preview) {
  return { materials: { [$("material-name").value]: { [key]: materialValue(key, v) } }, preview };
}

function bindControls() {
  $("light-index").addEventListener("change", fillControls);
  $("material-name").addEventListener("change", fillControls);
  $("light-color").addEventListener("input", (e) => send(lightUpdate({ color: unhex(e.target.value) })));
  $("light-intensity-range").addEventListener("input", (e) => {
    const v = intensity0 * 10 ** +e.target.value;
    $("light-intensity").value = fmt(v);
    send({ ...lightUpdate({ intensity: v }), preview: true });
  });
  $("light-intensity-range").addEventListener("change", () => send({ preview: false }));
  $("light-intensity").addEventListener("change", (e) => send(lightUpdate({ intensity: numberOrText(e.target.value) })));
  for (const key of ["ior", "sigma_s", "sigma_a"]) {
    $(`mat-${key}-range`).addEventListener("input", (e) => {
      $(`mat-${key}`).value = fmt(+e.target.value);
      send(materialUpdate(key, +e.target.value, true));
    });
    $(`mat-${key}-range`).addEventListener("change", () => send({ preview: false }));
    $(`mat-${key}`).addEventListener("change", (e) => send(materialUpdate(key, numberOrText(e.target.value), false)));
  }
  $("reset").addEventListener("click", () => post("/api/reset"));
  $("frame-index").addEventListener("input", (e) => send({ volume: { frame: +e.target.value } }));
  $("play").addEventListener("click", () => {
    playing = !playing;
    $("play").textContent = playing ? "pause" : "play";
    if (playing) nextVolumeFrame();
  });
}

let playing = false;
function nextVolumeFrame() {
  const s = viewer.state;
  const frame = s.volume.frame + 1 >= s.frames ? 0 : s.volume.frame + 1;
  s.volume.frame = frame;
  $("frame-index").value = frame;
  $("frame-label").textContent = `frame ${frame}`;
  send({ volume: { frame } });
}

function showStats(meta) {
  $("stats").textContent =
    `${meta.width}×${meta.height}${meta.preview ? " (preview)" : ""} · ${fmt(meta.ms)} ms · ` +
    `${fmt(meta.fps)} fps · frame ${meta.seq}` + (meta.passes > 1 ? ` · pass ${meta.passes}` : "") +
    Object.entries(meta.reduced || {}).map(([k, v]) => ` · ${k} ${v} (preview)`).join("") +
    ` · reran ${meta.recomputed.length} of ${viewer.state ? viewer.state.stages.length : "?"} stages`;
  const stages = viewer.state ? viewer.state.stages : Object.keys(meta.timings);
  $("timings").innerHTML = stages.map((name) => {
    const ms = meta.timings[name];
    return ms === undefined
      ? `<tr class="kept"><td>${name}</td><td>kept</td></tr>`
      : `<tr class="reran"><td>${name}</td><td>${ms.toFixed(1)} ms</td></tr>`;
  }).join("");
}

// ------------------------------------------------------------------ the overlay: light gizmos
function lightScreen(i) { // the light's marker in CSS pixels of the overlay, or null
  const light = viewer.state && viewer.state.lights[i];
  if (!light || !light.position) return null;
  const p = project(viewer.state.camera, light.position);
  if (!p) return null;
  const box = $("overlay").getBoundingClientRect();
  return [p[0] * box.width, p[1] * box.height];
}
viewer.lightScreen = lightScreen;

function drawOverlay() {
  const canvas = $("overlay"), box = canvas.getBoundingClientRect();
  canvas.width = box.width;
  canvas.height = box.height;
  const ctx = canvas.getContext("2d");
  if (!viewer.state) return;
  viewer.state.lights.forEach((light, i) => {
    const p = lightScreen(i);
    if (!p) return;
    ctx.strokeStyle = i === +($("light-index").value || 0) ? "#ffd479" : "#aaa";
    ctx.lineWidth = 2;
    ctx.beginPath();
    ctx.arc(p[0], p[1], 8, 0, 2 * Math.PI);
    ctx.stroke();
    ctx.fillStyle = hex(light.color);
    ctx.beginPath();
    ctx.arc(p[0], p[1], 3, 0, 2 * Math.PI);
    ctx.fill();
  });
}

// ------------------------------------------------------------------ mouse
let drag = null;
const mode = () => document.querySelector("input[name=mode]:checked").value;

function at(event) { // the mouse in [0, 1]² of the image and in CSS pixels
  const box = $("overlay").getBoundingClientRect();
  const px = [event.clientX - box.left, event.clientY - box.top];
  return { x: px[0] / box.width, y: px[1] / box.height, px, box };
}

function moveLight(index, x, y, depthFrom) {
  const cam = viewer.state.camera, light = viewer.state.lights[index];
  const depth = dot(sub(depthFrom, cam.origin), basis(cam).f);
  light.position = unproject(cam, x, y, Math.max(depth, 1e-3));
  send({ lights: { [index]: { position: light.position } }, preview: true });
  drawOverlay();
}

function paintAt(x, y) {
  const cam = viewer.state.camera;
  const depth = dot(sub(cam.target, cam.origin), basis(cam).f);
  post("/api/paint", {
    field: $("brush-field").value, center: unproject(cam, x, y, depth),
    radius: +$("brush-radius").value, amount: +$("brush-amount").value,
  });
}

function onDown(event) {
  if (!viewer.state) return;
  event.preventDefault();
  const m = at(event);
  const index = +($("light-index").value || 0);
  const marker = lightScreen(index);
  const light = viewer.state.lights[index];
  if (marker && Math.hypot(marker[0] - m.px[0], marker[1] - m.px[1]) < 14) {
    drag = { kind: "light", index, start: light.position.slice() };
  } else if (mode() === "light" && light && light.position) {
    drag = { kind: "light", index, start: light.position.slice() };
    moveLight(index, m.x, m.y, drag.start);
  } else if (mode() === "paint") {
    drag = { kind: "paint", last: 0 };
    paintAt(m.x, m.y);
  } else {
    const pan = event.shiftKey || event.button === 2;
    drag = { kind: pan ? "pan" : "orbit", x: event.clientX, y: event.clientY,
      cam: JSON.parse(JSON.stringify(viewer.state.camera)) };
  }
}

function onMove(event) {
  if (!drag) return;
  const m = at(event);
  if (drag.kind === "light") return moveLight(drag.index, m.x, m.y, drag.start);
  if (drag.kind === "paint") {
    if (event.timeStamp - drag.last > 60) { drag.last = event.timeStamp; paintAt(m.x, m.y); }
    return;
  }
  const dx = event.clientX - drag.x, dy = event.clientY - drag.y, c = drag.cam;
  const offset = sub(c.origin, c.target), radius = Math.hypot(...offset);
  let origin, target = c.target;
  if (drag.kind === "orbit") {
    const az = Math.atan2(offset[0], offset[2]) - dx * 0.01;
    const el = Math.min(1.5, Math.max(-1.5, Math.asin(offset[1] / radius) + dy * 0.01));
    origin = add(c.target, mul([Math.cos(el) * Math.sin(az), Math.sin(el), Math.cos(el) * Math.cos(az)], radius));
  } else {
    const b = basis(c), scale = (2 * radius * b.t) / m.box.width;
    const shift = add(mul(b.r, -dx * scale), mul(b.u, dy * scale));
    origin = add(c.origin, shift);
    target = add(c.target, shift);
  }
  Object.assign(viewer.state.camera, { origin, target });
  send({ camera: { origin, target }, preview: true });
  drawOverlay();
}

function onUp() {
  if (!drag) return;
  drag = null;
  send({ preview: false });
}

let wheelTimer = null;
function onWheel(event) {
  if (!viewer.state) return;
  event.preventDefault();
  const c = viewer.state.camera;
  const offset = mul(sub(c.origin, c.target), Math.exp(event.deltaY * 0.001));
  c.origin = add(c.target, offset);
  send({ camera: { origin: c.origin }, preview: true });
  clearTimeout(wheelTimer);
  wheelTimer = setTimeout(() => send({ preview: false }), 200);
}

const overlay = $("overlay");
overlay.addEventListener("mousedown", onDown);
window.addEventListener("mousemove", onMove);
window.addEventListener("mouseup", onUp);
overlay.addEventListener("wheel", onWheel, { passive: false });
overlay.addEventListener("contextmenu", (e) => e.preventDefault());
window.addEventListener("resize", drawOverlay);

bindControls();
loadState().then(connect);
