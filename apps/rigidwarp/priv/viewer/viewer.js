// rigidwarp viewer: draws the committed frames served by rw_viewer (live from
// a running simulation's frame ring, or played back from a frames file).
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

const $ = (id) => document.getElementById(id);
const state = { scene: null, frames: [], index: 0, playing: true, simTime: 0, follow: true,
                lastPoll: -1, done: false, status: {} };
// for tests and the curious: window.rwViewer.frameTime, .bodies, .ready
window.rwViewer = { ready: false, frameTime: null, bodies: 0, frames: 0 };

const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
renderer.setPixelRatio(window.devicePixelRatio);
$('view').appendChild(renderer.domElement);
const scene3 = new THREE.Scene();
scene3.background = new THREE.Color(0x1d2126);
const camera = new THREE.PerspectiveCamera(45, 1, 0.05, 1e6);
const controls = new OrbitControls(camera, renderer.domElement);
scene3.add(new THREE.HemisphereLight(0xffffff, 0x404050, 1.2));
const sun = new THREE.DirectionalLight(0xffffff, 1.5);
sun.position.set(1, 2, 1.5);
scene3.add(sun);

let spheres = null;            // InstancedMesh, one instance per body
let idToInstance = new Map();

function resize() {
  const el = $('view');
  renderer.setSize(el.clientWidth, el.clientHeight, false);
  camera.aspect = el.clientWidth / Math.max(1, el.clientHeight);
  camera.updateProjectionMatrix();
}
window.addEventListener('resize', resize);

async function getJSON(path) {
  const r = await fetch(path, { cache: 'no-store' });
  if (!r.ok) throw new Error(`${path}: HTTP ${r.status}`);
  return r.json();
}

const v3 = (a) => new THREE.Vector3(a[0], a[1], a[2]);

function buildFixtures(fixtures, bounds) {
  const solid = new THREE.MeshStandardMaterial({ color: 0x8a8f98, roughness: 0.8, metalness: 0.1 });
  for (const f of fixtures) {
    if (f.shape === 'plane') {
      const n = v3(f.normal).normalize();
      const size = Math.max(20, bounds.getSize(new THREE.Vector3()).length() * 3);
      const mesh = new THREE.Mesh(new THREE.PlaneGeometry(size, size),
        new THREE.MeshStandardMaterial({ color: 0x3c4450, roughness: 1, side: THREE.DoubleSide }));
      mesh.quaternion.setFromUnitVectors(new THREE.Vector3(0, 0, 1), n);
      mesh.position.copy(n.clone().multiplyScalar(f.offset));
      scene3.add(mesh);
      const grid = new THREE.GridHelper(size, Math.min(200, Math.round(size)), 0x59626e, 0x48505b);
      grid.quaternion.setFromUnitVectors(new THREE.Vector3(0, 1, 0), n);
      grid.position.copy(n.clone().multiplyScalar(f.offset + 1e-3));
      scene3.add(grid);
    } else if (f.shape === 'cylinder') {
      const mesh = new THREE.Mesh(new THREE.CylinderGeometry(f.radius, f.radius, 2 * f.half_length, 48), solid);
      mesh.quaternion.setFromUnitVectors(new THREE.Vector3(0, 1, 0), v3(f.axis).normalize());
      mesh.position.copy(v3(f.position));
      scene3.add(mesh);
      bounds.expandByPoint(v3(f.position));
    } else if (f.shape === 'box') {
      const [hx, hy, hz] = f.half_extents;
      const geo = new THREE.BoxGeometry(2 * hx, 2 * hy, 2 * hz);
      const obj = f.hollow
        ? new THREE.LineSegments(new THREE.EdgesGeometry(geo), new THREE.LineBasicMaterial({ color: 0xa0a8b4 }))
        : new THREE.Mesh(geo, solid);
      obj.position.copy(v3(f.position));
      scene3.add(obj);
      bounds.expandByPoint(v3(f.position).add(new THREE.Vector3(hx, hy, hz)));
      bounds.expandByPoint(v3(f.position).sub(new THREE.Vector3(hx, hy, hz)));
    }
  }
}

function buildSpheres(list) {
  const geo = new THREE.SphereGeometry(1, 24, 16);
  const mat = new THREE.MeshStandardMaterial({ roughness: 0.45, metalness: 0.05 });
  spheres = new THREE.InstancedMesh(geo, mat, Math.max(1, list.length));
  spheres.count = list.length;
  const color = new THREE.Color();
  list.forEach((s, i) => {
    idToInstance.set(s.id, { i, r: s.radius });
    color.setHSL((i * 0.618034) % 1, 0.55, 0.55);
    spheres.setColorAt(i, color);
  });
  scene3.add(spheres);
}

const m4 = new THREE.Matrix4(), q4 = new THREE.Quaternion(), p3 = new THREE.Vector3(), s3 = new THREE.Vector3();
function showFrame(frame) {
  for (const b of frame.bodies) {
    const inst = idToInstance.get(b.id);
    if (!inst) continue;
    p3.set(b.p[0], b.p[1], b.p[2]);
    if (b.q) q4.set(b.q[0], b.q[1], b.q[2], b.q[3]); else q4.identity();
    s3.set(inst.r, inst.r, inst.r);
    spheres.setMatrixAt(inst.i, m4.compose(p3, q4, s3));
  }
  spheres.instanceMatrix.needsUpdate = true;
  window.rwViewer.frameTime = frame.t;
  $('time').textContent = `t = ${frame.t} ms`;
}

function fitCamera(frame, bounds) {
  for (const b of frame.bodies) bounds.expandByPoint(v3(b.p));
  const centre = bounds.getCenter(new THREE.Vector3());
  const radius = Math.max(1, bounds.getSize(new THREE.Vector3()).length() / 2);
  controls.target.copy(centre);
  camera.position.copy(centre).add(new THREE.Vector3(0.35, 0.45, 1).normalize().multiplyScalar(radius * 3.2));
  camera.near = radius / 1000; camera.far = radius * 100;
  camera.updateProjectionMatrix();
  controls.update();
}

function setIndex(i) {
  if (state.frames.length === 0) return;
  state.index = Math.max(0, Math.min(state.frames.length - 1, i));
  state.simTime = state.frames[state.index].t;
  $('scrub').value = String(state.index);
  $('frameinfo').textContent = `${state.index + 1} / ${state.frames.length}`;
  showFrame(state.frames[state.index]);
}

async function poll() {
  if (state.done) return;
  try {
    const fresh = await getJSON(`api/frames?after=${state.lastPoll}`);
    if (fresh.length > 0) {
      state.frames.push(...fresh);
      state.lastPoll = fresh[fresh.length - 1].t;
      $('scrub').max = String(state.frames.length - 1);
      window.rwViewer.frames = state.frames.length;
      if (state.follow && state.scene.source === 'live') setIndex(state.frames.length - 1);
      else $('frameinfo').textContent = `${state.index + 1} / ${state.frames.length}`;
    }
    if (fresh.length === 0 && state.lastPoll >= state.scene.end_ms) state.done = true;
    setTimeout(poll, fresh.length >= 200 ? 0 : 200);
  } catch (e) {
    setTimeout(poll, 1000);
  }
}

async function pollStatus() {
  try {
    const s = await getJSON('api/status');
    state.status = s;
    $('gvt').textContent = `GVT = ${s.gvt} ms of ${s.end_ms}`;
    $('realtime').textContent = s.realtime_factor !== undefined ? `realtime ×${s.realtime_factor.toFixed(2)}` : 'realtime –';
    $('rollbacks').textContent = s.rollbacks !== undefined ? `rollbacks ${s.rollbacks}` : 'rollbacks – (playback)';
  } catch (e) { /* the server may be gone: keep the last numbers */ }
  if (state.scene.source === 'live') setTimeout(pollStatus, 500);
}

let lastWall = performance.now();
function animate(now) {
  const dt = now - lastWall;
  lastWall = now;
  if (state.playing && state.frames.length > 0 && !(state.follow && state.scene.source === 'live')) {
    state.simTime += dt * Number($('speed').value);
    let i = state.index;
    while (i + 1 < state.frames.length && state.frames[i + 1].t <= state.simTime) i++;
    if (i !== state.index) setIndex(i);
    else if (i === state.frames.length - 1 && state.done) state.simTime = state.frames[i].t;
  }
  controls.update();
  renderer.render(scene3, camera);
  requestAnimationFrame(animate);
}

function togglePlay() {
  state.playing = !state.playing;
  if (state.playing && state.index >= state.frames.length - 1 && state.done) setIndex(0);
  $('play').textContent = state.playing ? 'pause' : 'play';
}

async function main() {
  resize();
  const sc = await getJSON('api/scene');
  state.scene = sc;
  $('name').textContent = sc.name;
  $('source').textContent = sc.source === 'live' ? '(live)' : '(playback)';
  $('bodies').textContent = `bodies ${sc.spheres.length}`;
  window.rwViewer.bodies = sc.spheres.length;
  const bounds = new THREE.Box3();
  buildSpheres(sc.spheres);
  const first = await getJSON('api/frames?after=-1');
  if (first.length === 0) throw new Error('no frames yet');
  state.frames = first;
  window.rwViewer.frames = first.length;
  state.lastPoll = first[first.length - 1].t;
  $('scrub').max = String(first.length - 1);
  buildFixtures(sc.fixtures, bounds);
  fitCamera(first[0], bounds);
  setIndex(0);
  $('play').addEventListener('click', togglePlay);
  window.addEventListener('keydown', (e) => { if (e.code === 'Space') { e.preventDefault(); togglePlay(); } });
  $('scrub').addEventListener('input', () => { state.follow = false; setIndex(Number($('scrub').value)); });
  poll();
  pollStatus();
  requestAnimationFrame(animate);
  window.rwViewer.ready = true;
}

main().catch((e) => { $('error').hidden = false; $('error').textContent = `viewer: ${e.message}`; });
