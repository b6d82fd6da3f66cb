// The live view's page: a Foxglove WebSocket client (JSON channels of abd_joint_sim/live)
// drawing the bodies with three.js, the simulated time, the real-time factor, a strip chart
// of the joint angles, and buttons calling the server's pause/unpause/step/reset services.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

const COLOURS = ['#3366cc', '#dc7a12', '#2f9e44', '#c2255c', '#7048e8', '#8d5524', '#0b7285'];
const CHART_SECONDS = 10;
const $ = (id) => document.getElementById(id);

// Exposed for tests and benchmarks.
const live = window.live = {
  connected: false, simTime: null, rtf: null, paused: null, messages: 0, frames: 0,
  latencies: [],       // wall seconds from a publish (status.wall_time) to the drawing of it
  errors: [],
};

// ---------------------------------------------------------------- three.js scene ----
const view = $('view');
const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
renderer.setPixelRatio(window.devicePixelRatio);
view.appendChild(renderer.domElement);
const scene = new THREE.Scene();
scene.background = new THREE.Color(0xf4f4f2);
const camera = new THREE.PerspectiveCamera(45, 1, 0.01, 200);
camera.up.set(0, 0, 1);                       // z up, as in ROS and the scenes
camera.position.set(1.15, -1.25, 0.85);
const controls = new OrbitControls(camera, renderer.domElement);
controls.target.set(0.1, 0, 0.3);
controls.update();
scene.add(new THREE.HemisphereLight(0xffffff, 0x777777, 1.6));
const sun = new THREE.DirectionalLight(0xffffff, 1.6);
sun.position.set(2, -3, 4);
scene.add(sun);
const grid = new THREE.GridHelper(4, 40, 0x999999, 0xcccccc);
grid.rotation.x = Math.PI / 2;                // the XY plane
scene.add(grid);
scene.add(new THREE.AxesHelper(0.2));

const frames = new Map([['world', scene]]);
function frame(name) {
  let f = frames.get(name);
  if (!f) {
    f = new THREE.Group();
    f.name = name;
    frames.set(name, f);
    scene.add(f);
  }
  return f;
}

function setPose(obj, pose) {
  const p = pose.position, q = pose.orientation;
  obj.position.set(p.x, p.y, p.z);
  obj.quaternion.set(q.x, q.y, q.z, q.w);
}

function material(c) {
  return new THREE.MeshStandardMaterial({
    color: new THREE.Color(c.r, c.g, c.b), transparent: c.a < 1, opacity: c.a,
    roughness: 0.6, metalness: 0.1 });
}

const entities = new Map();
function drawEntity(e) {
  const old = entities.get(e.id);
  if (old) old.removeFromParent();
  const group = new THREE.Group();
  const add = (mesh, prim) => { const g = new THREE.Group(); setPose(g, prim.pose); g.add(mesh); group.add(g); };
  for (const c of e.cubes || []) {
    add(new THREE.Mesh(new THREE.BoxGeometry(c.size.x, c.size.y, c.size.z), material(c.color)), c);
  }
  for (const s of e.spheres || []) {
    const m = new THREE.Mesh(new THREE.SphereGeometry(0.5, 24, 16), material(s.color));
    m.scale.set(s.size.x, s.size.y, s.size.z);
    add(m, s);
  }
  for (const c of e.cylinders || []) {
    // three's cylinders stand on y, Foxglove's (and URDF's) on z
    const m = new THREE.Mesh(new THREE.CylinderGeometry(0.5, 0.5, 1, 32), material(c.color));
    m.scale.set(c.size.x, c.size.z, c.size.y);
    m.rotation.x = Math.PI / 2;
    add(m, c);
  }
  for (const model of e.models || []) {
    // mesh files are not fetched: a wire box marks where the mesh sits
    const m = new THREE.Mesh(new THREE.BoxGeometry(0.05, 0.05, 0.05),
      new THREE.MeshBasicMaterial({ color: 0x888888, wireframe: true }));
    m.userData.url = model.url;
    add(m, model);
  }
  frame(e.frame_id).add(group);
  entities.set(e.id, group);
}

function onTransforms(msg) {
  for (const t of msg.transforms) {
    const child = frame(t.child_frame_id);
    const parent = frame(t.parent_frame_id);
    if (child.parent !== parent) parent.add(child);
    child.position.set(t.translation.x, t.translation.y, t.translation.z);
    child.quaternion.set(t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w);
  }
}

// ------------------------------------------------------------------- strip chart ----
const history = [];        // [t, positions]
let jointNames = [];
function onJointStates(msg) {
  const t = msg.timestamp.sec + msg.timestamp.nsec * 1e-9;
  if (history.length && t < history[history.length - 1][0]) history.length = 0;   // reset
  history.push([t, msg.position]);
  while (history.length && history[0][0] < t - CHART_SECONDS) history.shift();
  if (msg.name.join() !== jointNames.join()) {
    jointNames = msg.name;
    $('legend').innerHTML = jointNames.map((n, i) =>
      `<span style="color:${COLOURS[i % COLOURS.length]}">■ ${n}</span>`).join('');
  }
  chartDirty = true;
}
let chartDirty = false;
function drawChart() {
  const cv = $('chart'), g = cv.getContext('2d');
  g.clearRect(0, 0, cv.width, cv.height);
  if (!history.length) return;
  const t1 = history[history.length - 1][0], t0 = t1 - CHART_SECONDS;
  let lo = Infinity, hi = -Infinity;
  for (const [, p] of history) for (const v of p) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
  if (hi - lo < 0.2) { const m = (hi + lo) / 2; lo = m - 0.1; hi = m + 0.1; }
  const x = (t) => (t - t0) / CHART_SECONDS * cv.width;
  const y = (v) => cv.height - 6 - (v - lo) / (hi - lo) * (cv.height - 12);
  g.strokeStyle = '#eee'; g.beginPath(); g.moveTo(0, y(0)); g.lineTo(cv.width, y(0)); g.stroke();
  jointNames.forEach((_, j) => {
    g.strokeStyle = COLOURS[j % COLOURS.length];
    g.beginPath();
    history.forEach(([t, p], k) => (k ? g.lineTo(x(t), y(p[j])) : g.moveTo(x(t), y(p[j]))));
    g.stroke();
  });
  g.fillStyle = '#666'; g.font = '11px sans-serif';
  g.fillText(hi.toFixed(2), 2, 11); g.fillText(lo.toFixed(2), 2, cv.height - 2);
}

// ----------------------------------------------------------------------- status ----
let pendingWall = null;
function onStatus(msg) {
  live.simTime = msg.sim_time;
  live.rtf = msg.real_time_factor;
  live.paused = msg.paused;
  $('sim-time').textContent = `${msg.sim_time.toFixed(3)} s`;
  $('rtf').textContent = msg.real_time_factor > 0 ? msg.real_time_factor.toFixed(2) : '–';
  $('state').textContent = msg.fault ? 'fault' : (msg.paused ? 'paused' : 'running');
  $('solver').textContent = `${msg.converged ? 'converged' : 'NOT converged'}, ${msg.newton_iterations} it.`;
  if (msg.fault) $('message').textContent = msg.fault;
  $('title').textContent = `abd_joint_sim live (${msg.source})`;
  if (typeof msg.wall_time === 'number') pendingWall = msg.wall_time;
}

// ---------------------------------------------------------- Foxglove WebSocket ----
let ws = null;
const subscriptions = new Map();      // subscription id -> topic
const services = new Map();           // name -> id
const calls = new Map();              // call id -> name
let nextCall = 1;
const decoder = new TextDecoder();
const handlers = { '/scene': (m) => m.entities.forEach(drawEntity), '/tf': onTransforms,
                   '/joint_states': onJointStates, '/status': onStatus };

async function connect() {
  const cfg = await (await fetch('/config.json')).json();
  ws = new WebSocket(`ws://${location.hostname}:${cfg.ws_port}`,
                     ['foxglove.sdk.v1', 'foxglove.websocket.v1']);
  ws.binaryType = 'arraybuffer';
  ws.onopen = () => { live.connected = true; $('conn').textContent = 'connected'; $('conn').className = 'value ok'; };
  ws.onclose = () => {
    live.connected = false; $('conn').textContent = 'disconnected (retrying)'; $('conn').className = 'value bad';
    subscriptions.clear(); services.clear();
    setTimeout(connect, 1000);
  };
  ws.onmessage = (ev) => {
    if (typeof ev.data === 'string') return onControl(JSON.parse(ev.data));
    const view = new DataView(ev.data);
    const op = view.getUint8(0);
    if (op === 1) {                   // message data: subscription id, log time, payload
      const topic = subscriptions.get(view.getUint32(1, true));
      const handler = handlers[topic];
      live.messages += 1;
      if (handler) handler(JSON.parse(decoder.decode(new Uint8Array(ev.data, 13))));
    } else if (op === 3) {            // service call response
      const callId = view.getUint32(5, true), n = view.getUint32(9, true);
      const answer = JSON.parse(decoder.decode(new Uint8Array(ev.data, 13 + n)));
      const name = calls.get(callId);
      $('message').textContent = `${name}: ${answer.message}`;
      calls.delete(callId);
      // nothing is published while paused: the answer says so
      if (answer.success && name === 'pause') { live.paused = true; $('state').textContent = 'paused'; }
    }
  };
}

function onControl(msg) {
  if (msg.op === 'advertise') {
    const subs = [];
    for (const ch of msg.channels) {
      if (!(ch.topic in handlers) || ch.encoding !== 'json') continue;
      const id = subscriptions.size + 1;
      subscriptions.set(id, ch.topic);
      subs.push({ id, channelId: ch.id });
    }
    ws.send(JSON.stringify({ op: 'subscribe', subscriptions: subs }));
  } else if (msg.op === 'advertiseServices') {
    for (const s of msg.services) services.set(s.name, s.id);
  } else if (msg.op === 'serviceCallFailure') {
    $('message').textContent = `${calls.get(msg.callId)} failed: ${msg.message}`;
  } else if (msg.op === 'status') {
    $('message').textContent = msg.message;
  }
}

function callService(name) {
  if (!ws || ws.readyState !== WebSocket.OPEN || !services.has(name)) {
    $('message').textContent = `${name}: not available`;
    return;
  }
  const callId = nextCall++;
  calls.set(callId, name);
  const enc = new TextEncoder().encode('json'), payload = new TextEncoder().encode('{}');
  const buf = new Uint8Array(13 + enc.length + payload.length);
  const dv = new DataView(buf.buffer);
  dv.setUint8(0, 2);
  dv.setUint32(1, services.get(name), true);
  dv.setUint32(5, callId, true);
  dv.setUint32(9, enc.length, true);
  buf.set(enc, 13);
  buf.set(payload, 13 + enc.length);
  ws.send(buf);
}
for (const name of ['pause', 'unpause', 'step', 'reset']) $(name).onclick = () => callService(name);

// ------------------------------------------------------------------------- loop ----
function resize() {
  const w = view.clientWidth, h = view.clientHeight;
  renderer.setSize(w, h);
  camera.aspect = w / Math.max(h, 1);
  camera.updateProjectionMatrix();
}
window.addEventListener('resize', resize);
resize();
function animate() {
  renderer.render(scene, camera);
  live.frames += 1;
  if (pendingWall !== null) {
    live.latencies.push(Date.now() / 1000 - pendingWall);
    if (live.latencies.length > 2000) live.latencies.shift();
    pendingWall = null;
  }
  if (chartDirty) { drawChart(); chartDirty = false; }
  requestAnimationFrame(animate);
}
requestAnimationFrame(animate);
connect().catch((err) => { live.errors.push(String(err)); $('message').textContent = String(err); });
