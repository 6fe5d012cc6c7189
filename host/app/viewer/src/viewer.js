// The point-cloud viewer of report.html. slscan writes the cloud into the page as a JSON block
// (<script type="application/json" id="slscan-cloud">) and inlines this bundle after it, so the
// page opens from disk with no network.
//
// Cloud format (written by host/app/report_html.cpp): positions quantised to uint16 over the
// cloud's bounding box (origin + q * scale, mm), normals as int8 (n * 127), both base64.
//
// When the first frame is drawn the viewer element gets data-status="drawn",
// data-points-drawn=N and data-nonblank-pixels=M (pixels of the canvas that differ from the
// background), so a headless browser can check that the page really rendered the cloud.
import { BufferAttribute, BufferGeometry, Color, PerspectiveCamera, Points, PointsMaterial, Scene, Vector3, WebGLRenderer } from 'three';
import { OrbitControls } from 'three/examples/jsm/controls/OrbitControls.js';

const BACKGROUND = 0x20242a;

function decodeBase64(text) {
  const binary = atob(text);
  const bytes = new Uint8Array(binary.length);
  for (let i = 0; i < binary.length; ++i) bytes[i] = binary.charCodeAt(i);
  return bytes;
}

function fail(element, message) {
  element.dataset.status = 'error';
  element.dataset.error = message;
  const note = document.createElement('p');
  note.className = 'viewer-error';
  note.textContent = 'The 3D viewer could not start: ' + message;
  element.appendChild(note);
}

function readCloud() {
  const block = document.getElementById('slscan-cloud');
  if (!block) throw new Error('the page holds no cloud (#slscan-cloud is missing)');
  const cloud = JSON.parse(block.textContent);
  const count = cloud.count;
  const q = new Uint16Array(decodeBase64(cloud.positions).buffer);
  const n = new Int8Array(decodeBase64(cloud.normals).buffer);
  if (q.length !== 3 * count) throw new Error(`positions hold ${q.length / 3} points, the header says ${count}`);
  if (n.length !== 0 && n.length !== 3 * count) throw new Error(`normals hold ${n.length / 3} points, not ${count}`);
  const positions = new Float32Array(3 * count);
  for (let i = 0; i < count; ++i)
    for (let k = 0; k < 3; ++k) positions[3 * i + k] = cloud.origin[k] + q[3 * i + k] * cloud.scale[k];
  return { count, positions, normals: n, cloud };
}

// Colour by height (blue low, orange high) and shade by the (outward) normal toward a light
// above and behind the default eye, so a person sees both the shape and which way the surfaces
// face.
function colours(positions, normals, count, zmin, zmax) {
  const out = new Float32Array(3 * count);
  const light = new Vector3(0.5, -1.0, 1.2).normalize();
  const low = new Color(0x2c7bb6), high = new Color(0xfdae61), c = new Color();
  const span = zmax > zmin ? zmax - zmin : 1;
  for (let i = 0; i < count; ++i) {
    c.copy(low).lerp(high, (positions[3 * i + 2] - zmin) / span);
    let shade = 0.85;
    if (normals.length) {
      const d = (normals[3 * i] * light.x + normals[3 * i + 1] * light.y + normals[3 * i + 2] * light.z) / 127;
      shade = 0.25 + 0.75 * Math.max(0, d);
    }
    // Vertex colours are linear and the output is sRGB: shade in sRGB terms, or the dark sides
    // come out barely darker than the lit ones.
    const linear = Math.pow(shade, 2.2);
    out[3 * i] = c.r * linear;
    out[3 * i + 1] = c.g * linear;
    out[3 * i + 2] = c.b * linear;
  }
  return out;
}

function countNonBlankPixels(gl, width, height) {
  const pixels = new Uint8Array(4 * width * height);
  gl.readPixels(0, 0, width, height, gl.RGBA, gl.UNSIGNED_BYTE, pixels);
  const br = (BACKGROUND >> 16) & 255, bg = (BACKGROUND >> 8) & 255, bb = BACKGROUND & 255;
  let count = 0;
  for (let i = 0; i < pixels.length; i += 4)
    if (Math.abs(pixels[i] - br) + Math.abs(pixels[i + 1] - bg) + Math.abs(pixels[i + 2] - bb) > 12) ++count;
  return count;
}

function start() {
  const element = document.getElementById('viewer');
  if (!element) return;
  let data;
  try {
    data = readCloud();
  } catch (e) {
    fail(element, e.message);
    return;
  }
  let renderer;
  try {
    renderer = new WebGLRenderer({ antialias: false, preserveDrawingBuffer: true });
  } catch (e) {
    fail(element, 'WebGL is not available in this browser (' + e.message + ')');
    return;
  }
  const width = element.clientWidth || 800, height = element.clientHeight || 600;
  renderer.setPixelRatio(1);
  renderer.setSize(width, height);
  renderer.setClearColor(BACKGROUND);
  element.appendChild(renderer.domElement);

  const geometry = new BufferGeometry();
  geometry.setAttribute('position', new BufferAttribute(data.positions, 3));
  geometry.computeBoundingBox();
  geometry.computeBoundingSphere();
  const box = geometry.boundingBox;
  geometry.setAttribute('color', new BufferAttribute(colours(data.positions, data.normals, data.count, box.min.z, box.max.z), 3));
  const sphere = geometry.boundingSphere;
  // A point about two sample spacings wide: the cloud reads as a surface at the default zoom.
  const material = new PointsMaterial({ size: data.cloud.point_size_mm || 0.5, vertexColors: true, sizeAttenuation: true });
  const points = new Points(geometry, material);

  const scene = new Scene();
  scene.add(points);
  const camera = new PerspectiveCamera(35, width / height, sphere.radius / 100, sphere.radius * 100);
  camera.up.set(0, 0, 1);  // the turntable axis is +z
  const distance = sphere.radius / Math.sin((35 / 2) * Math.PI / 180) * 1.1;
  camera.position.copy(sphere.center).add(new Vector3(0.8, -1.0, 0.55).normalize().multiplyScalar(distance));
  camera.lookAt(sphere.center);

  const controls = new OrbitControls(camera, renderer.domElement);
  controls.target.copy(sphere.center);
  controls.update();
  const draw = () => renderer.render(scene, camera);
  controls.addEventListener('change', draw);
  window.addEventListener('resize', () => {
    const w = element.clientWidth, h = element.clientHeight;
    if (!w || !h) return;
    camera.aspect = w / h;
    camera.updateProjectionMatrix();
    renderer.setSize(w, h);
    draw();
  });
  const reset = document.getElementById('viewer-reset');
  if (reset)
    reset.addEventListener('click', () => {
      controls.reset();
      draw();
    });

  draw();
  const gl = renderer.getContext();
  element.dataset.nonblankPixels = String(countNonBlankPixels(gl, renderer.domElement.width, renderer.domElement.height));
  element.dataset.pointsDrawn = String(renderer.info.render.points);
  const rect = renderer.domElement.getBoundingClientRect();
  element.dataset.canvasRect = [rect.left, rect.top, rect.width, rect.height].map(Math.round).join(',');
  element.dataset.status = 'drawn';
}

start();
