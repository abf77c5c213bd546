// The robot page: the arm drawn from armtwin's own FK link frames of the model in use, the twin
// and measured TCP, the window error chart, the metrics table, the model and recent events, all
// from one live stream of the robot's state (at most 30 updates a second); and the error per
// second over the history the service keeps (the last hour by default), read every 5 s.
import * as THREE from "three";

const id = decodeURIComponent(location.pathname.replace(/^\/robot\//, ""));
document.getElementById("robot-id").textContent = id;
document.title = `armtwin: ${id}`;

// ---- 3D view (z up, metres, the robot's output frame)
const canvas = document.getElementById("view");
const renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
renderer.setPixelRatio(window.devicePixelRatio || 1);
const scene = new THREE.Scene();
scene.background = new THREE.Color(0xf4f6fa);
const camera = new THREE.PerspectiveCamera(45, 1, 0.01, 100);
camera.up.set(0, 0, 1);
scene.add(new THREE.HemisphereLight(0xffffff, 0x8890a0, 2.0));
const sun = new THREE.DirectionalLight(0xffffff, 1.5);
sun.position.set(2, -3, 4);
scene.add(sun);
const grid = new THREE.GridHelper(2, 20, 0xb8bfcc, 0xdde1ea);
grid.rotation.x = Math.PI / 2;
scene.add(grid);
scene.add(new THREE.AxesHelper(0.25));

const linkMaterial = new THREE.MeshStandardMaterial({ color: 0x4b6584, metalness: 0.2, roughness: 0.6 });
const jointMaterial = new THREE.MeshStandardMaterial({ color: 0x2d3a4f });
const links = [];
const joints = [];
const unitCylinder = new THREE.CylinderGeometry(0.035, 0.035, 1, 20);
const jointSphere = new THREE.SphereGeometry(0.05, 20, 14);
const twinTcp = new THREE.Group();
twinTcp.add(new THREE.Mesh(new THREE.SphereGeometry(0.025, 16, 12), new THREE.MeshStandardMaterial({ color: 0x2563eb })));
twinTcp.add(new THREE.AxesHelper(0.12));
scene.add(twinTcp);
const measuredTcp = new THREE.Group();
measuredTcp.add(new THREE.Mesh(new THREE.SphereGeometry(0.025, 16, 12), new THREE.MeshStandardMaterial({ color: 0xf97316, transparent: true, opacity: 0.8 })));
measuredTcp.add(new THREE.AxesHelper(0.09));
measuredTcp.visible = false;
scene.add(measuredTcp);

const yAxis = new THREE.Vector3(0, 1, 0);
function drawArm(frames) {
  while (joints.length < frames.length) {
    const sphere = new THREE.Mesh(jointSphere, jointMaterial);
    joints.push(sphere);
    scene.add(sphere);
  }
  while (links.length < frames.length - 1) {
    const cylinder = new THREE.Mesh(unitCylinder, linkMaterial);
    links.push(cylinder);
    scene.add(cylinder);
  }
  const points = frames.map((f) => new THREE.Vector3(...f.position_m));
  points.forEach((p, i) => joints[i].position.copy(p));
  for (let i = 0; i + 1 < points.length; i++) {
    const from = points[i], to = points[i + 1];
    const along = new THREE.Vector3().subVectors(to, from);
    const length = along.length();
    links[i].visible = length > 1e-6;
    if (!links[i].visible) continue;
    links[i].position.copy(from).addScaledVector(along, 0.5);
    links[i].quaternion.setFromUnitVectors(yAxis, along.divideScalar(length));
    links[i].scale.set(1, length, 1);
  }
  const tcp = frames[frames.length - 1];
  twinTcp.position.set(...tcp.position_m);
  twinTcp.quaternion.set(...tcp.quaternion_xyzw);
}

// A turntable camera: drag turns, the wheel zooms.
const orbit = { azimuth: -0.9, elevation: 0.45, distance: 2.6, target: new THREE.Vector3(0, 0, 0.4) };
function placeCamera() {
  const { azimuth, elevation, distance, target } = orbit;
  camera.position.set(
    target.x + distance * Math.cos(elevation) * Math.cos(azimuth),
    target.y + distance * Math.cos(elevation) * Math.sin(azimuth),
    target.z + distance * Math.sin(elevation));
  camera.lookAt(target);
}
let drag = null;
canvas.addEventListener("pointerdown", (e) => { drag = { x: e.clientX, y: e.clientY }; canvas.setPointerCapture(e.pointerId); });
canvas.addEventListener("pointerup", () => { drag = null; });
canvas.addEventListener("pointermove", (e) => {
  if (!drag) return;
  orbit.azimuth -= (e.clientX - drag.x) * 0.01;
  orbit.elevation = Math.max(-1.4, Math.min(1.4, orbit.elevation + (e.clientY - drag.y) * 0.01));
  drag = { x: e.clientX, y: e.clientY };
  requestRender();
});
canvas.addEventListener("wheel", (e) => {
  e.preventDefault();
  orbit.distance = Math.max(0.5, Math.min(20, orbit.distance * Math.exp(e.deltaY * 0.001)));
  requestRender();
}, { passive: false });

function resize() {
  const width = canvas.clientWidth, height = canvas.clientHeight;
  if (canvas.width !== Math.floor(width * renderer.getPixelRatio()) || canvas.height !== Math.floor(height * renderer.getPixelRatio())) {
    renderer.setSize(width, height, false);
    camera.aspect = width / Math.max(1, height);
    camera.updateProjectionMatrix();
  }
}
let renderPending = false;
function requestRender() {
  if (renderPending) return;
  renderPending = true;
  requestAnimationFrame(() => {
    renderPending = false;
    resize();
    placeCamera();
    renderer.render(scene, camera);
    canvas.dataset.frames = String(Number(canvas.dataset.frames || 0) + 1);
  });
}
window.addEventListener("resize", requestRender);
requestRender();

// ---- error chart (a small canvas chart: two series over the last two minutes)
const chart = document.getElementById("chart");
const series = [];
// The span grows with the page's age up to two minutes, so the first seconds already fill it.
const CHART_MAX_SPAN_S = 120;
function drawChart() {
  const ctx = chart.getContext("2d");
  const ratio = window.devicePixelRatio || 1;
  const width = chart.clientWidth, height = chart.clientHeight;
  chart.width = width * ratio; chart.height = height * ratio;
  ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
  ctx.clearRect(0, 0, width, height);
  const left = 44, bottom = height - 20, top = 8, right = width - 8;
  const now = performance.now() / 1000;
  const span = series.length ? Math.min(CHART_MAX_SPAN_S, Math.max(10, now - series[0].t)) : 10;
  const visible = series.filter((p) => now - p.t <= span);
  let max = 0;
  for (const p of visible) max = Math.max(max, p.position_mm, p.angle_mrad);
  max = max > 0 ? max * 1.15 : 1;
  ctx.strokeStyle = "#dde1ea"; ctx.fillStyle = "#6b7385"; ctx.font = "11px system-ui"; ctx.lineWidth = 1;
  for (let i = 0; i <= 4; i++) {
    const y = bottom - (bottom - top) * i / 4;
    ctx.beginPath(); ctx.moveTo(left, y); ctx.lineTo(right, y); ctx.stroke();
    ctx.fillText((max * i / 4).toPrecision(3), 2, y + 4);
  }
  ctx.fillText(`last ${span.toFixed(0)} s`, right - 70, height - 4);
  const x = (t) => right - (now - t) / span * (right - left);
  const y = (v) => bottom - v / max * (bottom - top);
  for (const [key, color] of [["position_mm", "#2563eb"], ["angle_mrad", "#dc2626"]]) {
    ctx.strokeStyle = color; ctx.lineWidth = 2; ctx.beginPath();
    visible.forEach((p, i) => (i ? ctx.lineTo(x(p.t), y(p[key])) : ctx.moveTo(x(p.t), y(p[key]))));
    ctx.stroke();
  }
  chart.dataset.points = String(series.length);
}

// ---- history (window statistics the service keeps by the second and, further back, by the
// minute; read every 5 s)
const SVG = "http://www.w3.org/2000/svg";
const historySvg = document.getElementById("history");
function svgElement(name, attributes, text) {
  const element = document.createElementNS(SVG, name);
  for (const [key, value] of Object.entries(attributes)) element.setAttribute(key, value);
  if (text !== undefined) element.textContent = text;
  return element;
}
// Rows without pairs are absent from the answer: a line breaks across them rather than joining
// two rows over a gap. A row is `step` seconds long (1, or 60 for a minute).
function historyPaths(rows, x, y, value) {
  let d = "", next = null;
  for (const row of rows) {
    d += `${row.t === next ? "L" : "M"}${x(row.t).toFixed(1)},${y(value(row)).toFixed(1)}`;
    next = row.t + row.step;
  }
  return d;
}
// Incidents among the robot's recent events (the live stream's last ten), marked on the history
// at their source time: alarms (position, angle, collision, payload), restarts, gaps and the
// flight recorder's files.
const INCIDENTS = { alarm: "#dc2626", restart: "#7c3aed", gap: "#d97706", recorded: "#059669" };
let recentEvents = [];
let lastHistory = null;
function drawHistory(history) {
  lastHistory = history;
  const seconds = history.seconds;
  // Minutes before the first second kept, then the seconds.
  const minutes = (history.minutes || []).filter((m) => !seconds.length || m.t + 60 <= seconds[0].t);
  const rows = minutes.map((m) => ({ ...m, step: 60 })).concat(seconds.map((s) => ({ ...s, step: 1 })));
  const width = historySvg.clientWidth || 600, height = historySvg.clientHeight || 160;
  historySvg.setAttribute("viewBox", `0 0 ${width} ${height}`);
  const left = 44, bottom = height - 18, top = 6, right = width - 8;
  const children = [];
  const last = history.t === null ? 0 : Math.floor(history.t);
  // The span grows with the history kept, from a minute up to all of it (an hour by default),
  // so that a young robot's seconds are not squeezed into the right edge.
  const oldest = rows.length ? rows[0].t : last;
  const first = Math.max(last - history.history_s, Math.min(oldest, last - 60));
  let max = 0;
  for (const s of rows) max = Math.max(max, s.position.max * 1000, s.angle.mae * 1000);
  max = max > 0 ? max * 1.15 : 1;
  const x = (t) => left + (t - first) / Math.max(1, last - first) * (right - left);
  const y = (v) => bottom - v / max * (bottom - top);
  for (let i = 0; i <= 4; i++) {
    const level = bottom - (bottom - top) * i / 4;
    children.push(svgElement("line", { x1: left, x2: right, y1: level, y2: level, stroke: "#dde1ea" }));
    children.push(svgElement("text", { x: 2, y: level + 4 }, (max * i / 4).toPrecision(3)));
  }
  const span = last - first;
  const spanText = span >= 120 ? `${(span / 60).toFixed(0)} min` : `${span} s`;
  children.push(svgElement("text", { x: right - 150, y: height - 3 }, `last ${spanText} of source time`));
  for (const [name, color, value] of [
    ["position-max", "#93c5fd", (s) => s.position.max * 1000],
    ["position-mae", "#2563eb", (s) => s.position.mae * 1000],
    ["angle-mae", "#dc2626", (s) => s.angle.mae * 1000]]) {
    children.push(svgElement("path", { "data-series": name, d: historyPaths(rows, x, y, value), fill: "none", stroke: color, "stroke-width": 1.5 }));
  }
  let marks = 0;
  for (const event of recentEvents) {
    const color = INCIDENTS[event.kind];
    const t = Number(event.t);
    if (!color || !(t >= first && t <= last + 1)) continue;
    const title = svgElement("title", {}, `t=${t.toFixed(3)} ${event.kind}: ${event.reason}`);
    const mark = svgElement("line", { "data-event": event.kind, x1: x(t), x2: x(t), y1: top, y2: bottom, stroke: color, "stroke-dasharray": "3 2" });
    mark.appendChild(title);
    children.push(mark);
    marks++;
  }
  historySvg.replaceChildren(...children);
  historySvg.dataset.marks = String(marks);
  historySvg.dataset.seconds = String(seconds.length);
  historySvg.dataset.minutes = String(minutes.length);
  historySvg.dataset.last = seconds.length ? String(seconds[seconds.length - 1].t) : "";
  document.getElementById("history-span").textContent = seconds.length
    ? `${seconds.length} s with pairs, t ${seconds[0].t} … ${seconds[seconds.length - 1].t}`
      + (minutes.length ? `; ${minutes.length} min before, from t ${minutes[0].t}` : "")
    : "no completed second yet";
}
async function readHistory() {
  try {
    const response = await fetch("/api/robot/history?id=" + encodeURIComponent(id));
    if (response.ok) drawHistory(await response.json());
  } catch (error) {
    // The next read tries again; the live stream's status says whether the service is there.
  }
}
readHistory();
setInterval(readHistory, 5000);

// ---- the flight recorder's files of this robot, newest first, each a download
const recordingsList = document.getElementById("recordings");
async function readRecordings() {
  try {
    const response = await fetch("/api/robot/recordings?id=" + encodeURIComponent(id));
    if (!response.ok) return;
    const files = (await response.json()).files.slice().reverse();
    const items = files.map((file) => {
      const li = document.createElement("li");
      const a = document.createElement("a");
      a.href = "/api/robot/recording?id=" + encodeURIComponent(id) + "&name=" + encodeURIComponent(file.name);
      a.download = file.name;
      a.textContent = file.name;
      li.append(a, ` (${(file.bytes / 1e6).toFixed(2)} MB)`);
      return li;
    });
    if (!items.length) {
      const li = document.createElement("li");
      li.textContent = "none yet";
      items.push(li);
    }
    recordingsList.replaceChildren(...items);
    recordingsList.dataset.files = String(files.length);
  } catch (error) {
    // The next read tries again.
  }
}
readRecordings();
setInterval(readRecordings, 5000);

// ---- tables
const ROWS = [["position", "mm", 1000], ["x", "mm", 1000], ["y", "mm", 1000], ["z", "mm", 1000],
  ["angle", "mrad", 1000], ["roll", "mrad", 1000], ["pitch", "mrad", 1000], ["yaw", "mrad", 1000], ["quat_distance", "", 1]];
function metricsTable(metrics) {
  const body = document.getElementById("metrics-rows");
  const fragment = document.createDocumentFragment();
  for (const [name, unit, scale] of ROWS) {
    const tr = document.createElement("tr");
    const label = document.createElement("td");
    label.textContent = unit ? `${name} (${unit})` : name;
    tr.appendChild(label);
    for (const set of [metrics.cumulative, metrics.window.stats ?? metrics.window]) {
      for (const stat of ["mae", "rmse", "max"]) {
        const td = document.createElement("td");
        td.className = "num";
        td.textContent = (set[name][stat] * scale).toFixed(4);
        tr.appendChild(td);
      }
    }
    fragment.appendChild(tr);
  }
  body.replaceChildren(fragment);
}
function poseRow(rowId, label, stamped) {
  const tr = document.getElementById(rowId);
  const values = stamped ? [stamped.x, stamped.y, stamped.z, stamped.roll, stamped.pitch, stamped.yaw].map((v) => v.toFixed(4)).concat(stamped.t.toFixed(3)) : Array(7).fill("–");
  tr.replaceChildren(...[label, ...values].map((text, i) => {
    const td = document.createElement("td");
    td.textContent = text;
    if (i) td.className = "num";
    return td;
  }));
}

// What the gateway read of the controller. Its texts come from the controller: shown as text only.
function controllerText(controller) {
  if (!controller) return "";
  const tcp = controller.tcp_offset
    ? ` · tcp_offset [${controller.tcp_offset.map((v) => v.toFixed(4)).join(", ")}]` : "";
  const problem = controller.dashboard_error ? ` · dashboard server: ${controller.dashboard_error}` : "";
  return `\ncontroller   ${controller.model ?? "model unknown"} · serial ${controller.serial ?? "unknown"}${tcp}${problem}`;
}

function update(message) {
  const state = message.state;
  if (message.frames) drawArm(message.frames);
  if (state.measured) {
    const m = state.measured;
    measuredTcp.visible = true;
    measuredTcp.position.set(m.x, m.y, m.z);
    measuredTcp.quaternion.set(m.qx, m.qy, m.qz, m.qw);
  }
  requestRender();
  poseRow("tcp-twin", "twin", state.twin);
  poseRow("tcp-measured", "measured", state.measured);
  const metrics = state.metrics;
  const window = metrics.window;
  series.push({ t: performance.now() / 1000, position_mm: window.position.mae * 1000, angle_mrad: window.angle.mae * 1000 });
  while (series.length > 4000) series.shift();
  drawChart();
  document.getElementById("chart-now").textContent =
    `now ${(window.position.mae * 1000).toFixed(3)} mm · ${(window.angle.mae * 1000).toFixed(3)} mrad over ${window.n} pairs (${window.seconds} s)`;
  metricsTable(metrics);
  const causes = Object.entries(message.rejected_by_cause).map(([c, n]) => `${c} ${n}`).join(", ");
  document.getElementById("counts").textContent =
    `${message.poses} poses · ${metrics.paired} paired · ${metrics.unpaired} unpaired · ${metrics.rejected} rejected${causes ? " (" + causes + ")" : ""} · epoch ${metrics.epoch}`;
  const alarm = document.getElementById("alarm-state");
  const active = [state.alarms.position ? "position" : "", state.alarms.angle ? "angle" : ""].filter(Boolean);
  alarm.textContent = active.length ? `ALARM: ${active.join(", ")}` : "no alarm";
  alarm.className = active.length ? "alarm" : "";
  const tool = state.tool.map((v) => v.toFixed(4)).join(", ");
  document.getElementById("model").textContent =
    `model        ${state.model}\ncalibration  ${state.calibration ?? "none (nominal)"}\ntool         [${tool}] (m, rotation vector rad)\nframe        ${state.frame}${controllerText(state.controller)}\njoints (rad) ${state.joints ? state.joints.q.map((q) => q.toFixed(4)).join(", ") : "–"}${jointStateText(state.joint_state)}${effortText(state.effort)}`;
  const newestEvent = message.events.length ? message.events[message.events.length - 1] : null;
  const previousEvent = recentEvents.length ? recentEvents[recentEvents.length - 1] : null;
  recentEvents = message.events;
  if (lastHistory && JSON.stringify(newestEvent) !== JSON.stringify(previousEvent)) drawHistory(lastHistory);
  const list = document.getElementById("events");
  list.replaceChildren(...message.events.slice().reverse().map((event) => {
    const li = document.createElement("li");
    li.textContent = `t=${Number(event.t).toFixed(3)} ${event.kind}: ${event.reason}`;
    return li;
  }));
  document.getElementById("status").textContent = "live";
}

// The joint state the robot's source reports beside its angles, when it reports any.
function jointStateText(js) {
  if (!js) return "";
  const row = (label, values, digits) =>
    values ? `\n${label.padEnd(13)}${values.map((v) => v.toFixed(digits)).join(", ")}` : "";
  let text = row("temp (°C)", js.temperature_c, 1) + row("current (A)", js.current_a, 3) +
    row("torque (Nm)", js.torque_nm, 2) + row("model (Nm)", js.target_torque_nm, 2) + row("qd (rad/s)", js.qd, 4);
  if (js.robot_mode !== undefined) {
    const bits = [js.power_on ? "power on" : "power off", js.program_running ? "program running" : "",
      js.freedrive ? "freedrive" : ""].filter(Boolean).join(", ");
    text += `\nmode         robot ${js.robot_mode}, safety ${js.safety_mode}, ${bits}, speed ${(js.speed_scaling * 100).toFixed(0)} %`;
  }
  if (js.payload) text += `\npayload      ${js.payload.mass_kg} kg at [${js.payload.cog_m.join(", ")}] m`;
  return text;
}

// The effort of a robot with effort = true: model against measured torque, residual, observer,
// friction and payload.
function effortText(effort) {
  if (!effort) return "";
  const row = (label, values, digits) =>
    values ? `\n${label.padEnd(13)}${values.map((v) => (v === null ? "–" : v.toFixed(digits))).join(", ")}` : "";
  const latest = effort.latest;
  let text = "";
  if (latest) {
    text += `\neffort       ${latest.mode}, model on the ${latest.state} state`;
    text += row("τ model (Nm)", latest.model_nm, 2) + row("τ meas. (Nm)", latest.measured_nm, 2) +
      row("residual (Nm)", latest.residual_nm, 2) + row("observer (Nm)", latest.observer_nm, 2);
  }
  const window = effort.residual.window;
  if (window.stats.n) text += row(`rms ${window.seconds} s`, window.stats.rms_nm, 2);
  text += row("friction (Nm)", effort.friction.map((f) => (f ? f.coulomb_nm : null)), 2);
  if (effort.friction.some((f) => f && f.drift_nm !== null))
    text += row("drift (Nm)", effort.friction.map((f) => (f ? f.drift_nm : null)), 2);
  const payload = effort.payload;
  text += `\npayload used ${payload.in_use.mass_kg.toFixed(3)} kg (${payload.in_use.source})`;
  if (payload.estimate)
    text += `, identified ${payload.estimate.mass_kg.toFixed(3)} ± ${payload.estimate.mass_std_kg.toFixed(3)} kg`;
  if (effort.payload_mismatch) text += " MISMATCH";
  const active = effort.collision.active.map((on, k) => (on ? `joint ${k + 1}` : "")).filter(Boolean);
  text += `\ncollisions   ${effort.collision.count}${active.length ? " · NOW: " + active.join(", ") : ""}`;
  return text;
}

const source = new EventSource("/api/robot/stream?id=" + encodeURIComponent(id));
source.onmessage = (message) => update(JSON.parse(message.data));
source.onerror = () => { document.getElementById("status").textContent = "reconnecting…"; };
