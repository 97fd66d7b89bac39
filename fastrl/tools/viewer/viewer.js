// fastrl's rollout viewer: a small self-contained WebGL 1 renderer, no libraries.
//
// It reads the scene that fastrl/tools/viewer/scene.py embeds in <script id="scene">: static geoms
// (MuJoCo geom types, sizes in MuJoCo's convention, colours, pose in their body) and, per frame,
// every body's world pose [x, y, z, qw, qx, qy, qz]. Each geom becomes a triangle mesh with its
// size baked in; a frame draws every geom at (body pose) * (geom pose). The world is z-up, as
// in MuJoCo. The page around it (fastrl/tools/viewer/html.py) provides the controls and the
// <pre id="errors"> that records any error, which the headless-browser test reads.
(function () {
  "use strict";

  const PLANE = 0, SPHERE = 2, CAPSULE = 3, ELLIPSOID = 4, CYLINDER = 5, BOX = 6, MESH = 7;
  const SKY = [0.88, 0.91, 0.95];
  const LIGHT = [0.35, 0.25, 1.0];  // towards the (directional) light, z-up
  const scene = JSON.parse(document.getElementById("scene").textContent);
  const nframe = scene.nframe, nbody = scene.nbody, frames = scene.frames;
  const $ = (id) => document.getElementById(id);

  // ------------------------------------------------------------------ small vector/matrix math
  // Matrices are column-major Float32Array(16), as WebGL expects.

  function sub(a, b) { return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]; }
  function cross(a, b) { return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]; }
  function dot(a, b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
  function normalize(a) { const n = Math.hypot(a[0], a[1], a[2]) || 1; return [a[0] / n, a[1] / n, a[2] / n]; }

  function quatMul(a, b) {
    return [
      a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
      a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
      a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
      a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
    ];
  }

  function quatRotate(q, v) {
    const u = [q[1], q[2], q[3]], w = q[0];
    const t = cross(u, v).map((x) => 2 * x);
    const c = cross(u, t);
    return [v[0] + w * t[0] + c[0], v[1] + w * t[1] + c[1], v[2] + w * t[2] + c[2]];
  }

  function poseMatrix(p, q) {
    const n = Math.hypot(q[0], q[1], q[2], q[3]) || 1;
    const w = q[0] / n, x = q[1] / n, y = q[2] / n, z = q[3] / n;
    return new Float32Array([
      1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y), 0,
      2 * (x * y - w * z), 1 - 2 * (x * x + z * z), 2 * (y * z + w * x), 0,
      2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y), 0,
      p[0], p[1], p[2], 1,
    ]);
  }

  function matMul(a, b) {
    const out = new Float32Array(16);
    for (let c = 0; c < 4; c++)
      for (let r = 0; r < 4; r++) {
        let s = 0;
        for (let k = 0; k < 4; k++) s += a[k * 4 + r] * b[c * 4 + k];
        out[c * 4 + r] = s;
      }
    return out;
  }

  function perspective(fovy, aspect, near, far) {
    const f = 1 / Math.tan(fovy / 2), nf = 1 / (near - far);
    return new Float32Array([f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) * nf, -1, 0, 0, 2 * far * near * nf, 0]);
  }

  function lookAt(eye, target, up) {
    const z = normalize(sub(eye, target)), x = normalize(cross(up, z)), y = cross(z, x);
    return new Float32Array([
      x[0], y[0], z[0], 0, x[1], y[1], z[1], 0, x[2], y[2], z[2], 0,
      -dot(x, eye), -dot(y, eye), -dot(z, eye), 1,
    ]);
  }

  // ------------------------------------------------------------------ geometry
  // Builders return {pos, nrm}: flat arrays of non-indexed triangles in the geom's frame.

  function grid(rows, cols, point) {
    // A (rows+1) x (cols+1) parametric surface; point(i, j) -> [position, normal].
    const pos = [], nrm = [], pts = [];
    for (let i = 0; i <= rows; i++) for (let j = 0; j <= cols; j++) pts.push(point(i, j));
    const at = (i, j) => pts[i * (cols + 1) + j];
    for (let i = 0; i < rows; i++)
      for (let j = 0; j < cols; j++)
        for (const [a, b] of [[0, 0], [1, 0], [1, 1], [0, 0], [1, 1], [0, 1]]) {
          const [p, n] = at(i + a, j + b);
          pos.push(p[0], p[1], p[2]);
          nrm.push(n[0], n[1], n[2]);
        }
    return { pos, nrm };
  }

  function ellipsoid(rx, ry, rz) {
    return grid(16, 24, (i, j) => {
      const th = (Math.PI * i) / 16, ph = (2 * Math.PI * j) / 24;
      const u = [Math.sin(th) * Math.cos(ph), Math.sin(th) * Math.sin(ph), Math.cos(th)];
      return [[rx * u[0], ry * u[1], rz * u[2]], normalize([u[0] / rx, u[1] / ry, u[2] / rz])];
    });
  }

  function capsule(r, h) {
    // A sphere cut at the equator, its halves moved to z = +h and -h; the band between is the tube.
    return grid(17, 24, (i, j) => {
      const k = i <= 8 ? i : i - 1, th = (Math.PI * k) / 16, ph = (2 * Math.PI * j) / 24;
      const u = [Math.sin(th) * Math.cos(ph), Math.sin(th) * Math.sin(ph), Math.cos(th)];
      return [[r * u[0], r * u[1], r * u[2] + (i <= 8 ? h : -h)], u];
    });
  }

  function cylinder(r, h) {
    const side = grid(1, 32, (i, j) => {
      const ph = (2 * Math.PI * j) / 32, u = [Math.cos(ph), Math.sin(ph), 0];
      return [[r * u[0], r * u[1], i ? -h : h], u];
    });
    for (const s of [1, -1]) {
      const cap = grid(1, 32, (i, j) => {
        const ph = (2 * Math.PI * j * s) / 32;
        return [[i * r * Math.cos(ph), i * r * Math.sin(ph), s * h], [0, 0, s]];
      });
      side.pos.push(...cap.pos);
      side.nrm.push(...cap.nrm);
    }
    return side;
  }

  function box(hx, hy, hz) {
    const pos = [], nrm = [], h = [hx, hy, hz];
    for (let axis = 0; axis < 3; axis++)
      for (const s of [1, -1]) {
        const a = (axis + 1) % 3, b = (axis + 2) % 3, n = [0, 0, 0];
        n[axis] = s;
        const corner = (u, v) => { const p = [0, 0, 0]; p[axis] = s * h[axis]; p[a] = u * h[a]; p[b] = v * h[b]; return p; };
        for (const [u, v] of [[-1, -1], [1, -1], [1, 1], [-1, -1], [1, 1], [-1, 1]]) {
          pos.push(...corner(u, v));
          nrm.push(...n);
        }
      }
    return { pos, nrm };
  }

  function plane(hx, hy) {
    return grid(1, 1, (i, j) => [[(2 * i - 1) * hx, (2 * j - 1) * hy, 0], [0, 0, 1]]);
  }

  function mesh(m) {
    const pos = [], nrm = [], v = m.vert;
    for (let f = 0; f < m.face.length; f += 3) {
      const p = [0, 1, 2].map((k) => [v[3 * m.face[f + k]], v[3 * m.face[f + k] + 1], v[3 * m.face[f + k] + 2]]);
      const n = normalize(cross(sub(p[1], p[0]), sub(p[2], p[0])));
      for (const q of p) { pos.push(...q); nrm.push(...n); }
    }
    return { pos, nrm };
  }

  function geomShape(g) {
    const s = g.size, far = 50 * scene.radius;
    switch (g.type) {
      case PLANE: return plane(s[0] > 0 ? s[0] : far, s[1] > 0 ? s[1] : far);
      case SPHERE: return ellipsoid(s[0], s[0], s[0]);
      case CAPSULE: return capsule(s[0], s[1]);
      case ELLIPSOID: return ellipsoid(s[0], s[1], s[2]);
      case CYLINDER: return cylinder(s[0], s[1]);
      case BOX: return box(s[0], s[1], s[2]);
      case MESH: return mesh(scene.meshes[g.mesh]);
      default: return null;
    }
  }

  // ------------------------------------------------------------------ WebGL setup

  const canvas = $("view");
  const gl = canvas.getContext("webgl", { antialias: true, stencil: true });
  if (!gl) throw new Error("WebGL is not available in this browser");

  const VERTEX = `
    attribute vec3 a_pos; attribute vec3 a_nrm;
    uniform mat4 u_model; uniform mat4 u_viewproj;
    varying vec3 v_nrm; varying vec3 v_world;
    void main() {
      vec4 w = u_model * vec4(a_pos, 1.0);
      v_world = w.xyz;
      v_nrm = (u_model * vec4(a_nrm, 0.0)).xyz;
      gl_Position = u_viewproj * w;
    }`;
  const FRAGMENT = `
    #ifdef GL_FRAGMENT_PRECISION_HIGH
    precision highp float;
    #else
    precision mediump float;
    #endif
    uniform vec4 u_color; uniform vec3 u_eye; uniform vec3 u_sky;
    uniform float u_cell; uniform float u_fog; uniform float u_flat;
    varying vec3 v_nrm; varying vec3 v_world;
    void main() {
      if (u_flat > 0.0) { gl_FragColor = u_color; return; }  // shadows
      vec3 n = normalize(v_nrm), v = normalize(u_eye - v_world);
      if (dot(n, v) < 0.0) n = -n;
      vec3 l = normalize(vec3(${LIGHT.join(", ")}));
      float diffuse = max(dot(n, l), 0.0);
      float spec = 0.25 * pow(max(dot(n, normalize(l + v)), 0.0), 40.0);
      vec3 base = u_color.rgb;
      float fog = 0.0;
      if (u_cell > 0.0) {  // ground: a checker of u_cell squares fading into the sky
        vec2 c = floor(v_world.xy / u_cell);
        base *= 0.82 + 0.18 * mod(c.x + c.y, 2.0);
        fog = clamp(length(u_eye - v_world) / u_fog, 0.0, 1.0);
        spec = 0.0;
      }
      vec3 col = base * (0.4 + 0.6 * diffuse) + spec;
      gl_FragColor = vec4(mix(col, u_sky, fog * fog), u_color.a);
    }`;

  function compile(type, src) {
    const sh = gl.createShader(type);
    gl.shaderSource(sh, src);
    gl.compileShader(sh);
    if (!gl.getShaderParameter(sh, gl.COMPILE_STATUS)) throw new Error("shader: " + gl.getShaderInfoLog(sh));
    return sh;
  }

  const prog = gl.createProgram();
  gl.attachShader(prog, compile(gl.VERTEX_SHADER, VERTEX));
  gl.attachShader(prog, compile(gl.FRAGMENT_SHADER, FRAGMENT));
  gl.linkProgram(prog);
  if (!gl.getProgramParameter(prog, gl.LINK_STATUS)) throw new Error("program: " + gl.getProgramInfoLog(prog));
  gl.useProgram(prog);
  const loc = {};
  for (const name of ["u_model", "u_viewproj", "u_color", "u_eye", "u_sky", "u_cell", "u_fog", "u_flat"])
    loc[name] = gl.getUniformLocation(prog, name);
  const aPos = gl.getAttribLocation(prog, "a_pos"), aNrm = gl.getAttribLocation(prog, "a_nrm");
  gl.enableVertexAttribArray(aPos);
  gl.enableVertexAttribArray(aNrm);

  function upload(shape) {
    const buf = (data) => {
      const b = gl.createBuffer();
      gl.bindBuffer(gl.ARRAY_BUFFER, b);
      gl.bufferData(gl.ARRAY_BUFFER, new Float32Array(data), gl.STATIC_DRAW);
      return b;
    };
    return { pos: buf(shape.pos), nrm: buf(shape.nrm), count: shape.pos.length / 3 };
  }

  // A "nice" checker size near half the robot's reach: 0.1, 0.25, 0.5, 1, 2.5, ...
  const cell = (() => {
    const x = scene.radius / 2, e = Math.pow(10, Math.floor(Math.log10(x)));
    return e * [1, 2.5, 5, 10].find((m) => m * e >= x);
  })();

  const items = [];
  for (const g of scene.geoms) {
    const shape = geomShape(g);
    if (shape) items.push({ g, buf: upload(shape), cell: g.type === PLANE ? cell : 0 });
  }
  if (!scene.has_plane) {
    // No floor in the model: a grey ground at the lowest point, so motion reads against it.
    const g = { type: PLANE, body: 0, pos: [0, 0, scene.ground], quat: [1, 0, 0, 0], rgba: [0.75, 0.77, 0.8, 1] };
    items.push({ g, buf: upload(plane(50 * scene.radius, 50 * scene.radius)), cell });
  }
  // Goals (a goal env's targets): red spheres placed per frame, drawn after the robot.
  const markerItem = scene.nmarker
    ? { g: { rgba: [0.9, 0.15, 0.1, 0.85] }, buf: upload(ellipsoid(0.04 * scene.radius, 0.04 * scene.radius, 0.04 * scene.radius)) }
    : null;
  function markerPos(frame, i) {
    const o = (frame * scene.nmarker + i) * 3, m = scene.markers;
    return [m[o], m[o + 1], m[o + 2]];
  }
  // Opaque geoms first; translucent ones after, blended, without writing depth.
  items.sort((a, b) => (a.g.rgba[3] < 1) - (b.g.rgba[3] < 1));

  // ------------------------------------------------------------------ camera

  const cam = { azimuth: -70, elevation: 22, distance: 3.2 * scene.radius, target: bodyPos(0, scene.root) };

  function bodyPos(frame, body) {
    const o = (frame * nbody + body) * 7;
    return [frames[o], frames[o + 1], frames[o + 2]];
  }

  function bodyQuat(frame, body) {
    const o = (frame * nbody + body) * 7 + 3;
    return [frames[o], frames[o + 1], frames[o + 2], frames[o + 3]];
  }

  function eyeOf() {
    const az = (cam.azimuth * Math.PI) / 180, el = (cam.elevation * Math.PI) / 180, t = cam.target;
    return [t[0] + cam.distance * Math.cos(el) * Math.cos(az), t[1] + cam.distance * Math.cos(el) * Math.sin(az),
      t[2] + cam.distance * Math.sin(el)];
  }

  let drag = null;
  canvas.addEventListener("contextmenu", (e) => e.preventDefault());
  canvas.addEventListener("pointerdown", (e) => {
    drag = { x: e.clientX, y: e.clientY, pan: e.button === 2 || e.shiftKey };
    canvas.setPointerCapture(e.pointerId);
  });
  canvas.addEventListener("pointerup", () => { drag = null; });
  canvas.addEventListener("pointermove", (e) => {
    if (!drag) return;
    const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
    drag.x = e.clientX;
    drag.y = e.clientY;
    if (drag.pan) {
      // Move the target in the view plane; panning ends following.
      const eye = eyeOf(), fwd = normalize(sub(cam.target, eye)), right = normalize(cross(fwd, [0, 0, 1]));
      const up = cross(right, fwd), k = (cam.distance * 1.2) / canvas.clientHeight;
      cam.target = cam.target.map((t, i) => t - k * (dx * right[i] - dy * up[i]));
      $("follow").checked = false;
    } else {
      cam.azimuth -= dx * 0.4;
      cam.elevation = Math.max(-89, Math.min(89, cam.elevation + dy * 0.4));
    }
    requestDraw();
  });
  canvas.addEventListener("wheel", (e) => {
    e.preventDefault();
    cam.distance *= Math.exp(e.deltaY * 0.001);
    requestDraw();
  }, { passive: false });

  // ------------------------------------------------------------------ drawing

  function resize() {
    const dpr = window.devicePixelRatio || 1;
    const w = Math.max(1, Math.round(canvas.clientWidth * dpr)), h = Math.max(1, Math.round(canvas.clientHeight * dpr));
    if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
  }

  function geomMatrix(frame, g) {
    const bq = bodyQuat(frame, g.body), bp = bodyPos(frame, g.body);
    return poseMatrix(quatRotate(bq, g.pos).map((x, i) => x + bp[i]), quatMul(bq, g.quat));
  }

  function drawItem(item, model, rgba, cell) {
    const translucent = rgba[3] < 1;
    if (translucent) { gl.enable(gl.BLEND); gl.blendFunc(gl.SRC_ALPHA, gl.ONE_MINUS_SRC_ALPHA); gl.depthMask(false); }
    gl.uniformMatrix4fv(loc.u_model, false, model);
    gl.uniform4fv(loc.u_color, rgba);
    gl.uniform1f(loc.u_cell, cell);
    gl.bindBuffer(gl.ARRAY_BUFFER, item.buf.pos);
    gl.vertexAttribPointer(aPos, 3, gl.FLOAT, false, 0, 0);
    gl.bindBuffer(gl.ARRAY_BUFFER, item.buf.nrm);
    gl.vertexAttribPointer(aNrm, 3, gl.FLOAT, false, 0, 0);
    gl.drawArrays(gl.TRIANGLES, 0, item.buf.count);
    if (translucent) { gl.disable(gl.BLEND); gl.depthMask(true); }
  }

  // Shadows: every solid geom flattened onto the ground along the light, blended once per pixel
  // (the stencil keeps overlapping shadows from darkening twice).
  const shadowZ = scene.has_plane ? scene.geoms.find((g) => g.type === PLANE).pos[2] : scene.ground;
  const shadowMatrix = (() => {
    const kx = LIGHT[0] / LIGHT[2], ky = LIGHT[1] / LIGHT[2], h = shadowZ + 1e-3 * scene.radius;
    return new Float32Array([1, 0, 0, 0, 0, 1, 0, 0, -kx, -ky, 0, 0, kx * h, ky * h, h, 1]);
  })();

  function drawShadows(poses) {
    gl.uniform1f(loc.u_flat, 1);
    gl.enable(gl.STENCIL_TEST);
    gl.stencilFunc(gl.EQUAL, 0, 0xff);
    gl.stencilOp(gl.KEEP, gl.KEEP, gl.INCR);
    gl.enable(gl.POLYGON_OFFSET_FILL);
    gl.polygonOffset(-1, -4);
    items.forEach((it, i) => {
      if (!it.cell) drawItem(it, matMul(shadowMatrix, poses[i]), [0.1, 0.12, 0.15, 0.4], 0);
    });
    gl.disable(gl.POLYGON_OFFSET_FILL);
    gl.disable(gl.STENCIL_TEST);
  }

  function draw(frame) {
    resize();
    if ($("follow").checked) cam.target = bodyPos(frame, scene.root);
    const eye = eyeOf(), r = scene.radius;
    const proj = perspective((45 * Math.PI) / 180, canvas.width / canvas.height, 0.01 * r, 200 * r);
    gl.viewport(0, 0, canvas.width, canvas.height);
    gl.clearColor(SKY[0], SKY[1], SKY[2], 1);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT | gl.STENCIL_BUFFER_BIT);
    gl.enable(gl.DEPTH_TEST);
    gl.uniformMatrix4fv(loc.u_viewproj, false, matMul(proj, lookAt(eye, cam.target, [0, 0, 1])));
    gl.uniform3fv(loc.u_eye, eye);
    gl.uniform3fv(loc.u_sky, SKY);
    gl.uniform1f(loc.u_fog, 30 * r);
    gl.uniform1f(loc.u_flat, 0);
    const poses = items.map(({ g }) => geomMatrix(frame, g));
    items.forEach((it, i) => { if (it.cell) drawItem(it, poses[i], it.g.rgba, it.cell); });
    drawShadows(poses);
    gl.uniform1f(loc.u_flat, 0);
    items.forEach((it, i) => { if (!it.cell) drawItem(it, poses[i], it.g.rgba, 0); });
    for (let i = 0; markerItem && i < scene.nmarker; i++) {
      drawItem(markerItem, poseMatrix(markerPos(frame, i), [1, 0, 0, 0]), markerItem.g.rgba, 0);
    }
    const dropped = scene.overflow && scene.overflow.length ? scene.overflow[frame] : 0;
    $("overflow").textContent = dropped > 0 ? "contacts dropped: " + dropped : "";
    $("frame").textContent = String(frame);
    $("time").textContent = (frame * scene.dt).toFixed(2) + " s";
    $("slider").value = String(frame);
    document.body.dataset.drawn = String(Number(document.body.dataset.drawn || 0) + 1);
  }

  // ------------------------------------------------------------------ playback

  const state = { playing: true, time: 0, last: null, frame: 0, dirty: true };
  function requestDraw() { state.dirty = true; }

  function setPlaying(on) {
    state.playing = on;
    $("play").textContent = on ? "Pause" : "Play";
  }

  function seek(frame) {
    state.frame = Math.max(0, Math.min(nframe - 1, frame));
    state.time = state.frame * scene.dt;
    requestDraw();
  }

  $("slider").max = String(nframe - 1);
  $("nframe").textContent = String(nframe - 1);
  $("play").addEventListener("click", () => setPlaying(!state.playing));
  $("slider").addEventListener("input", (e) => { setPlaying(false); seek(Number(e.target.value)); });
  $("follow").addEventListener("change", requestDraw);
  window.addEventListener("resize", requestDraw);
  window.addEventListener("keydown", (e) => {
    if (e.key !== " " && /^(INPUT|SELECT)$/.test(e.target.tagName)) return;  // the control's own keys
    if (e.key === " ") { e.preventDefault(); setPlaying(!state.playing); }
    else if (e.key === "ArrowRight") { setPlaying(false); seek(state.frame + 1); }
    else if (e.key === "ArrowLeft") { setPlaying(false); seek(state.frame - 1); }
  });

  function tick(now) {
    if (state.playing && state.last !== null) {
      state.time = (state.time + ((now - state.last) / 1000) * Number($("speed").value)) % (nframe * scene.dt);
      const frame = Math.min(nframe - 1, Math.floor(state.time / scene.dt));
      if (frame !== state.frame) { state.frame = frame; state.dirty = true; }
    }
    state.last = now;
    if (state.dirty) { state.dirty = false; draw(state.frame); }
    requestAnimationFrame(tick);
  }

  $("title").textContent = scene.title;
  const start = /frame=(\d+)/.exec(window.location.hash);  // page.html#frame=N opens paused at N
  if (start) { setPlaying(false); seek(Number(start[1])); }
  draw(state.frame);
  document.body.dataset.status = "running";
  requestAnimationFrame(tick);
})();
