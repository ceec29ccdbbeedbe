// Camera math of the 3-D view, matching server/render/camera.h exactly: a look-at camera in
// physical µm (volume corner at the origin), right = forward × up, row 0 at the top; ortho
// images cover ortho_height µm vertically, perspective ones fov_y_degrees. The client keeps an
// orbit camera {projection, pivot, forward, up, distance, fov, orthoHeight} and converts it to
// and from the protocol's camera document (docs/render_json.md). Pure functions.

export const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
export const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
export const mul = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
export const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
export const cross = (a, b) =>
    [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
export const length = (a) => Math.sqrt(dot(a, a));
export const normalize = (a) => {
  const l = length(a);
  return l > 0 ? mul(a, 1 / l) : [0, 0, 0];
};

// Rotates v about unit axis k by angle (radians), Rodrigues' formula.
export function rotate(v, k, angle) {
  const c = Math.cos(angle), s = Math.sin(angle);
  return add(add(mul(v, c), mul(cross(k, v), s)), mul(k, dot(k, v) * (1 - c)));
}

// The volume's physical box [0, size·spacing].
export function volumeExtent(dataset) {
  return [0, 1, 2].map((a) => dataset.size[a] * (dataset.spacing?.[a] || 1));
}

// The orthonormal frame of forward/up as the server builds it (FromFrame).
export function frame(forward, up) {
  const f = normalize(forward);
  const r = normalize(cross(f, normalize(up)));
  return {forward: f, right: r, up: cross(r, f)};
}

// Standard view directions (camera.h): z looks along +z with rows along +y; y along -y rows +z;
// x along +x, image x = +y, rows +z; iso along (1,1,1)/√3 with up as close to -y as possible.
// A '-' preset looks from the other side (mirror image), same up.
export function presetFrame(name) {
  const table = {
    z: [[0, 0, 1], [0, -1, 0]], '-z': [[0, 0, -1], [0, -1, 0]],
    y: [[0, -1, 0], [0, 0, -1]], '-y': [[0, 1, 0], [0, 0, -1]],
    x: [[1, 0, 0], [0, 0, -1]], '-x': [[-1, 0, 0], [0, 0, -1]],
    iso: [normalize([1, 1, 1]), [0, -1, 0]],
  };
  const entry = table[name];
  if (!entry) throw new Error(`unknown view preset ${name}`);
  return frame(entry[0], entry[1]);
}

// An orbit camera fitted to the volume box as Camera::Standard fits it (aspect = width/height).
export function fitCamera(presetName, extent, aspect, projection = 'ortho', fov = 30) {
  const {forward, up, right} = presetFrame(presetName);
  const pivot = mul(extent, 0.5);
  const radius = length(extent) / 2;
  let halfW = 0, halfH = 0;
  for (let i = 0; i < 3; ++i) {
    halfW += Math.abs(right[i]) * extent[i] / 2;
    halfH += Math.abs(up[i]) * extent[i] / 2;
  }
  const orthoHeight = Math.max(2 * halfH, 2 * halfW / aspect);
  const halfV = fov * Math.PI / 360;
  const halfHor = Math.atan(Math.tan(halfV) * aspect);
  // Perspective: the sphere around the box in sight; ortho: the camera plane outside the box.
  const distance = projection === 'perspective' ? radius / Math.sin(Math.min(halfV, halfHor)) :
                                                  orthoHeight / (2 * Math.tan(halfV));
  return {projection, pivot, forward, up, distance, fov, orthoHeight};
}

// Protocol camera document → orbit camera. The pivot is the point of the view axis nearest to
// the volume's centre (the default camera's target), so orbiting turns about the specimen.
export function fromCameraDocument(doc, extent) {
  const fov = doc.fov_y_degrees ?? 30;
  const f = frame(sub(doc.target, doc.position), doc.up ?? [0, -1, 0]);
  const centre = mul(extent, 0.5);
  const depth = dot(sub(centre, doc.position), f.forward);
  const pivot = add(doc.position, mul(f.forward, depth));
  const focal = length(sub(doc.target, doc.position));
  const orthoHeight = doc.ortho_height ?? 2 * focal * Math.tan(fov * Math.PI / 360);
  const distance = doc.projection === 'perspective' ? Math.max(depth, 1e-6) :
                                                      orthoHeight / (2 * Math.tan(fov * Math.PI / 360));
  return {projection: doc.projection ?? 'ortho', pivot, forward: f.forward, up: f.up, distance, fov,
    orthoHeight};
}

// The eye / image-plane centre of an orbit camera. An orthographic camera stands outside the
// volume's bounding sphere (its rays start on the camera plane and run forward only).
export function cameraPosition(cam, extent) {
  let d = cam.distance;
  if (cam.projection !== 'perspective') d = Math.max(d, length(extent));
  return sub(cam.pivot, mul(cam.forward, d));
}

// Orbit camera → protocol camera document (look-at form).
export function toCameraDocument(cam, extent) {
  const position = cameraPosition(cam, extent);
  return {
    projection: cam.projection,
    position: position.map(round6),
    target: cam.pivot.map(round6),
    up: cam.up.map(round6),
    fov_y_degrees: cam.fov,
    ortho_height: round6(cam.orthoHeight),
  };
}

function round6(v) {
  return Math.round(v * 1e6) / 1e6;
}

// Orbit by dx, dy radians: turntable about the image's up axis, then tilt about its right axis.
export function orbit(cam, yaw, pitch) {
  const f0 = frame(cam.forward, cam.up);
  let forward = rotate(f0.forward, f0.up, -yaw);
  let right = normalize(cross(forward, f0.up));
  forward = rotate(forward, right, -pitch);
  const up = normalize(cross(right, forward));
  return {...cam, forward: normalize(forward), up};
}

// Pan by (dx, dy) µm along the image's right and up axes.
export function pan(cam, dxUm, dyUm) {
  const f = frame(cam.forward, cam.up);
  return {...cam, pivot: add(cam.pivot, add(mul(f.right, -dxUm), mul(f.up, dyUm)))};
}

// Zoom by `factor` (> 1 zooms in): the ortho height and the perspective distance shrink.
export function zoom(cam, factor) {
  const f = Math.min(Math.max(factor, 1e-3), 1e3);
  return {...cam, orthoHeight: cam.orthoHeight / f, distance: cam.distance / f};
}

// Rolls the image by `angle` radians about the view direction.
export function roll(cam, angle) {
  return {...cam, up: rotate(cam.up, normalize(cam.forward), angle)};
}

// µm per CSS pixel at the pivot's depth for a view `heightPx` tall.
export function umPerPixel(cam, heightPx) {
  if (cam.projection === 'perspective') {
    return 2 * cam.distance * Math.tan(cam.fov * Math.PI / 360) / heightPx;
  }
  return cam.orthoHeight / heightPx;
}

// The ray of image point (x, y) (pixels, centre of pixel i at i + 0.5) of a w × h image, as
// Camera::ImageRay: {origin, dir}.
export function imageRay(cam, extent, w, h, x, y) {
  const f = frame(cam.forward, cam.up);
  const pos = cameraPosition(cam, extent);
  const dx = x - w / 2, dy = h / 2 - y;
  if (cam.projection !== 'perspective') {
    const p = cam.orthoHeight / h;
    return {origin: add(pos, add(mul(f.right, dx * p), mul(f.up, dy * p))), dir: f.forward};
  }
  const s = 2 * Math.tan(cam.fov * Math.PI / 360) / h;
  return {origin: pos, dir: normalize(add(f.forward, add(mul(f.right, dx * s), mul(f.up, dy * s))))};
}

// Projects world point p into a w × h image: [x, y, depth] (depth along forward from the camera
// plane or eye); null when it lies behind (perspective: nearer than `near`).
export function project(cam, extent, w, h, p, near = 1e-3) {
  const f = frame(cam.forward, cam.up);
  const pos = cameraPosition(cam, extent);
  const d = sub(p, pos);
  const z = dot(d, f.forward);
  if (cam.projection !== 'perspective') {
    const scale = h / cam.orthoHeight;
    return [w / 2 + dot(d, f.right) * scale, h / 2 - dot(d, f.up) * scale, z];
  }
  if (z < near) return null;
  const s = h / (2 * Math.tan(cam.fov * Math.PI / 360));
  return [w / 2 + dot(d, f.right) / z * s, h / 2 - dot(d, f.up) / z * s, z];
}

// The rectangle where plane p[axis] = pos cuts the box [0, extent], as 4 corners (in order).
export function planeCorners(axis, pos, extent) {
  const [u, v] = [0, 1, 2].filter((a) => a !== axis);
  const corners = [];
  for (const [a, b] of [[0, 0], [1, 0], [1, 1], [0, 1]]) {
    const c = [0, 0, 0];
    c[axis] = pos;
    c[u] = a * extent[u];
    c[v] = b * extent[v];
    corners.push(c);
  }
  return corners;
}

// The plane's outline in image pixels: a list of segments [[x0, y0], [x1, y1]], each edge first
// clipped to the part in front of the camera (perspective: at least `near` before the eye).
export function planeOutline(cam, extent, w, h, axis, pos, near = 1e-3) {
  const corners = planeCorners(axis, pos, extent);
  const f = frame(cam.forward, cam.up);
  const eye = cameraPosition(cam, extent);
  const depth = (p) => dot(sub(p, eye), f.forward);
  const minDepth = cam.projection === 'perspective' ? near : 0;
  const segments = [];
  for (let i = 0; i < 4; ++i) {
    let a = corners[i], b = corners[(i + 1) % 4];
    const da = depth(a), db = depth(b);
    if (da < minDepth && db < minDepth) continue;
    // Clip the part behind the camera: the point where depth = minDepth.
    if (da < minDepth) a = add(a, mul(sub(b, a), (minDepth - da) / (db - da)));
    if (db < minDepth) b = add(b, mul(sub(a, b), (minDepth - db) / (da - db)));
    const pa = project(cam, extent, w, h, a, minDepth * 0.999);
    const pb = project(cam, extent, w, h, b, minDepth * 0.999);
    if (pa && pb) segments.push([[pa[0], pa[1]], [pb[0], pb[1]]]);
  }
  return segments;
}
