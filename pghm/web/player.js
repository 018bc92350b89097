// pghm's web player: an avatar baked by `pghm export --web`, drawn as pghm draws it.
//
// For frame f of the baked motion (pghm/web/bake.py):
//   1. the frame's canonical points, log-scales and colours: each group's mean plus its
//      principal components times the frame's coefficients (a few multiply-adds a value);
//   2. linear blend skinning on the GPU (shaders/web_skinning.vert.glsl, transform feedback):
//      mu = M c, M = sum_k w_k B_jk with the frame's bone transforms;
//   3. the order front to back: depths in float64 from the camera's float32 matrix, as the CPU
//      splatter computes them (pghm.splat), sorted by their float32 rounding;
//   4. the viewer's sprites (shaders/gaussian_sprite.*.glsl) into a float target with the
//      front-to-back blend (ONE_MINUS_DST_ALPHA, ONE), then the background under them
//      (shaders/composite.frag.glsl).
// Steps 1-2 run when the frame changes, 3 when the frame or the camera does, 4 when anything
// does: a paused, untouched view draws nothing.
//
// The camera is pghm render's (pghm/render/framing.py): an orbit around the rest body's
// bounding-box centre that follows the root across the floor, the body filling BODY_FILL of
// the image; at yaw 0, pitch 0 and no zoom or pan a frame is `pghm render --yaw 0` of it.
"use strict";

(function () {
  const FORMAT = 1;
  const ORBIT_DEGREES_PER_PIXEL = 0.4;
  const PITCH_LIMIT = 89;
  const ZOOM_PER_WHEEL_UNIT = 0.0015;
  const ZOOM_RANGE = [0.1, 20];
  const FRAME_KEY_STEP = 1;

  const message = document.getElementById("message");
  function fail(text) {
    message.textContent = text;
    message.style.display = "flex";
    throw new Error(text);
  }

  const data = JSON.parse(document.getElementById("pghm-data").textContent);
  if (data.format !== FORMAT) fail(`This page's data is format ${data.format}; this player reads ${FORMAT}.`);

  // ---- the data: base64 little-endian typed arrays --------------------------------------------
  const TYPES = { f4: Float32Array, f8: Float64Array, i1: Int8Array, u1: Uint8Array, u2: Uint16Array, i4: Int32Array };
  function decode(entry) {
    const text = atob(entry.data);
    const bytes = new Uint8Array(text.length);
    for (let i = 0; i < text.length; i++) bytes[i] = text.charCodeAt(i);
    return new TYPES[entry.dtype](bytes.buffer);
  }
  function group(entry, channels) {
    const basis = decode(entry.basis);
    return {
      mean: decode(entry.mean),
      basis,
      coefficients: decode(entry.coefficients),
      rank: entry.basis.shape[0],
      size: N * channels,
    };
  }
  const N = data.gaussians;
  const F = data.frames;
  const W_TEX = data.texture_width;
  const ROWS = Math.max(1, Math.ceil(N / W_TEX));
  const canonicalPoints = group(data.points, 3);
  const logScales = group(data.log_scales, 1);
  const colors = group(data.colors, 3);
  const transforms = decode(data.transforms); // (F, B, 3, 4)
  const BONES = data.transforms.shape[1];
  const BONE_ROWS = Math.max(1, Math.ceil((3 * BONES) / W_TEX));
  const roots = decode(data.roots); // (F, 3)

  // x_f = mean + sum_k a_fk q_k, into `out` (Float32Array of group.size).
  function rebuild(g, frame, out) {
    out.set(g.mean);
    for (let k = 0; k < g.rank; k++) {
      const a = g.coefficients[frame * g.rank + k];
      if (a === 0) continue;
      const q = g.basis.subarray(k * g.size, (k + 1) * g.size);
      for (let i = 0; i < g.size; i++) out[i] += a * q[i];
    }
    return out;
  }

  // ---- WebGL2 --------------------------------------------------------------------------------
  const canvas = document.getElementById("view");
  const gl = canvas.getContext("webgl2", {
    alpha: false, antialias: false, depth: false, stencil: false, premultipliedAlpha: false,
    preserveDrawingBuffer: true,
  });
  if (!gl) fail("This page needs a browser with WebGL2.");
  // Float accumulation as the viewer's RGBA32F; half floats where float blending is missing.
  const floatTarget = gl.getExtension("EXT_color_buffer_float");
  const floatBlend = gl.getExtension("EXT_float_blend");
  const ACCUM = floatTarget ? (floatBlend ? [gl.RGBA32F, gl.FLOAT] : [gl.RGBA16F, gl.HALF_FLOAT]) : [gl.RGBA8, gl.UNSIGNED_BYTE];

  function program(name, varyings) {
    const source = data.shaders[name];
    const made = gl.createProgram();
    for (const [type, text] of [[gl.VERTEX_SHADER, source.vertex], [gl.FRAGMENT_SHADER, source.fragment]]) {
      const shader = gl.createShader(type);
      gl.shaderSource(shader, text);
      gl.compileShader(shader);
      if (!gl.getShaderParameter(shader, gl.COMPILE_STATUS)) fail(`${name} shader: ${gl.getShaderInfoLog(shader)}`);
      gl.attachShader(made, shader);
    }
    if (varyings) gl.transformFeedbackVaryings(made, varyings, gl.SEPARATE_ATTRIBS);
    gl.linkProgram(made);
    if (!gl.getProgramParameter(made, gl.LINK_STATUS)) fail(`${name} program: ${gl.getProgramInfoLog(made)}`);
    const uniforms = {};
    const count = gl.getProgramParameter(made, gl.ACTIVE_UNIFORMS);
    for (let i = 0; i < count; i++) {
      const info = gl.getActiveUniform(made, i);
      uniforms[info.name] = gl.getUniformLocation(made, info.name);
    }
    return { program: made, uniforms };
  }
  const skinning = program("skinning", ["mean_scale", "color_opacity"]);
  const points = program("points");
  const quads = program("quads");
  const composite = program("composite");
  const LARGEST_POINT = gl.getParameter(gl.ALIASED_POINT_SIZE_RANGE)[1];

  function texture(width, height, format, type, filter) {
    const made = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, made);
    gl.texStorage2D(gl.TEXTURE_2D, 1, format, width, height);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, filter || gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, filter || gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
    return made;
  }
  function upload(made, width, height, format, values) {
    gl.bindTexture(gl.TEXTURE_2D, made);
    gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, width, height, format, gl.FLOAT, values);
  }
  function buffer(target, values, usage) {
    const made = gl.createBuffer();
    gl.bindBuffer(target, made);
    gl.bufferData(target, values, usage);
    return made;
  }

  // Skinning: per-Gaussian attributes in, (mean, scale) and (colour, opacity) out.
  const canonical = new Float32Array(N * 3);
  const logScale = new Float32Array(N);
  const color = new Float32Array(N * 3);
  const skinVao = gl.createVertexArray();
  gl.bindVertexArray(skinVao);
  function attribute(name, values, size, type, normalized, integer) {
    const location = gl.getAttribLocation(skinning.program, name);
    const made = buffer(gl.ARRAY_BUFFER, values, integer || normalized ? gl.STATIC_DRAW : gl.DYNAMIC_DRAW);
    gl.enableVertexAttribArray(location);
    if (integer) gl.vertexAttribIPointer(location, size, type, 0, 0);
    else gl.vertexAttribPointer(location, size, type, normalized, 0, 0);
    return made;
  }
  const canonicalBuffer = attribute("canonical", canonical, 3, gl.FLOAT, false, false);
  const logScaleBuffer = attribute("log_scale", logScale, 1, gl.FLOAT, false, false);
  const colorBuffer = attribute("color", color, 3, gl.FLOAT, false, false);
  attribute("bone_index", decode(data.skin.index), 4, gl.UNSIGNED_SHORT, false, true);
  // uint8 weights out of 255, normalised by the GPU to w / 255 (pghm/web/bake.py stores them so).
  attribute("bone_weight", decode(data.skin.weights), 4, gl.UNSIGNED_BYTE, true, false);
  gl.bindVertexArray(null);
  // Each output buffer holds whole texture rows, so that a texture upload can read it as it is.
  const meanScale = new Float32Array(ROWS * W_TEX * 4);
  const meanScaleOut = buffer(gl.TRANSFORM_FEEDBACK_BUFFER, meanScale.byteLength, gl.DYNAMIC_READ);
  const colorOpacityOut = buffer(gl.TRANSFORM_FEEDBACK_BUFFER, meanScale.byteLength, gl.DYNAMIC_COPY);
  gl.bindBuffer(gl.TRANSFORM_FEEDBACK_BUFFER, null);
  const feedback = gl.createTransformFeedback();
  const boneValues = new Float32Array(BONE_ROWS * W_TEX * 4);
  const boneTexture = texture(W_TEX, BONE_ROWS, gl.RGBA32F, gl.FLOAT);

  // Sprites: the viewer's textures, texel i for Gaussian i, and the draw order.
  const meanScaleTexture = texture(W_TEX, ROWS, gl.RGBA32F, gl.FLOAT);
  const colorOpacityTexture = texture(W_TEX, ROWS, gl.RGBA32F, gl.FLOAT);
  const orderTexture = texture(W_TEX, ROWS, gl.R32F, gl.FLOAT);
  const orderValues = new Float32Array(ROWS * W_TEX);
  const order = new Uint32Array(N);
  const emptyVao = gl.createVertexArray();
  let accum = null; // {texture, framebuffer, width, height}

  function skin(frame) {
    rebuild(canonicalPoints, frame, canonical);
    rebuild(logScales, frame, logScale);
    rebuild(colors, frame, color);
    for (const [made, values] of [[canonicalBuffer, canonical], [logScaleBuffer, logScale], [colorBuffer, color]]) {
      gl.bindBuffer(gl.ARRAY_BUFFER, made);
      gl.bufferSubData(gl.ARRAY_BUFFER, 0, values);
    }
    boneValues.set(transforms.subarray(frame * BONES * 12, (frame + 1) * BONES * 12));
    upload(boneTexture, W_TEX, BONE_ROWS, gl.RGBA, boneValues);
    gl.useProgram(skinning.program);
    gl.activeTexture(gl.TEXTURE0);
    gl.bindTexture(gl.TEXTURE_2D, boneTexture);
    gl.uniform1i(skinning.uniforms.bones, 0);
    gl.bindVertexArray(skinVao);
    gl.enable(gl.RASTERIZER_DISCARD);
    gl.bindTransformFeedback(gl.TRANSFORM_FEEDBACK, feedback);
    gl.bindBufferBase(gl.TRANSFORM_FEEDBACK_BUFFER, 0, meanScaleOut);
    gl.bindBufferBase(gl.TRANSFORM_FEEDBACK_BUFFER, 1, colorOpacityOut);
    gl.beginTransformFeedback(gl.POINTS);
    gl.drawArrays(gl.POINTS, 0, N);
    gl.endTransformFeedback();
    gl.bindBufferBase(gl.TRANSFORM_FEEDBACK_BUFFER, 0, null);
    gl.bindBufferBase(gl.TRANSFORM_FEEDBACK_BUFFER, 1, null);
    gl.bindTransformFeedback(gl.TRANSFORM_FEEDBACK, null);
    gl.disable(gl.RASTERIZER_DISCARD);
    gl.bindVertexArray(null);
    // The textures take the outputs on the GPU (buffer to texture); only the means come back,
    // for the depth order and the sprites' extent.
    for (const [made, target] of [[meanScaleOut, meanScaleTexture], [colorOpacityOut, colorOpacityTexture]]) {
      gl.bindBuffer(gl.PIXEL_UNPACK_BUFFER, made);
      gl.bindTexture(gl.TEXTURE_2D, target);
      gl.texSubImage2D(gl.TEXTURE_2D, 0, 0, 0, W_TEX, ROWS, gl.RGBA, gl.FLOAT, 0);
    }
    gl.bindBuffer(gl.PIXEL_UNPACK_BUFFER, null);
    gl.bindBuffer(gl.COPY_READ_BUFFER, meanScaleOut);
    gl.getBufferSubData(gl.COPY_READ_BUFFER, 0, meanScale, 0, N * 4);
    gl.bindBuffer(gl.COPY_READ_BUFFER, null);
  }

  // Front to back: an LSD radix sort on the depths (keyBits) as float32 bit patterns made monotonic
  // (negative: all bits flipped; positive: the sign bit set), four passes of 8 bits, stable, so
  // equal keys keep the index order. float32 keys order depths the CPU splatter's float64 ones
  // order alike except within 1e-7 of each other, sub-micrometre at a few metres.
  const keys = new Uint32Array(N);
  const keyBits = new Float32Array(keys.buffer);
  const sortedKeys = new Uint32Array(N);
  const sortedOrder = new Uint32Array(N);
  const counts = new Uint32Array(256);
  function sortByDepth() {
    for (let i = 0; i < N; i++) keys[i] = keys[i] & 0x80000000 ? ~keys[i] >>> 0 : (keys[i] | 0x80000000) >>> 0;
    let fromKeys = keys, fromOrder = order, toKeys = sortedKeys, toOrder = sortedOrder;
    for (let shift = 0; shift < 32; shift += 8) {
      counts.fill(0);
      for (let i = 0; i < N; i++) counts[(fromKeys[i] >>> shift) & 255]++;
      for (let b = 0, total = 0; b < 256; b++) { const c = counts[b]; counts[b] = total; total += c; }
      for (let i = 0; i < N; i++) {
        const slot = counts[(fromKeys[i] >>> shift) & 255]++;
        toKeys[slot] = fromKeys[i];
        toOrder[slot] = fromOrder[i];
      }
      [fromKeys, toKeys] = [toKeys, fromKeys];
      [fromOrder, toOrder] = [toOrder, fromOrder];
    }
    // Four passes: the result is back in `keys` and `order`.
  }

  // The sprites' order front to back and their extent (pghm/gl/footprint.py): the screen box
  // holding every sprite, and the largest point half side, e sqrt(max(a, c)) of cov2d.
  const SPEC = data.spec;
  const RADIUS = Math.sqrt(2 * Math.log(1 / SPEC.ALPHA_MIN)) * 1.001 + 1e-3; // e at opacity 1
  function sortAndMeasure(cam, width, height) {
    const m = cam.worldToCamera;
    const f = cam.focal;
    const [cx, cy] = cam.principal;
    const limitX = (SPEC.FRUSTUM_CLAMP * width) / (2 * f);
    const limitY = (SPEC.FRUSTUM_CLAMP * height) / (2 * f);
    let [left, top, right, bottom, half] = [Infinity, Infinity, -Infinity, -Infinity, 0];
    for (let i = 0; i < N; i++) {
      const x = meanScale[4 * i];
      const y = meanScale[4 * i + 1];
      const z = meanScale[4 * i + 2];
      const tz = m[8] * x + m[9] * y + m[10] * z + m[11];
      keyBits[i] = tz; // the sort key: the depth rounded to float32
      order[i] = i;
      if (!(tz > SPEC.NEAR_PLANE)) continue;
      const tx = m[0] * x + m[1] * y + m[2] * z + m[3];
      const ty = m[4] * x + m[5] * y + m[6] * z + m[7];
      const s2 = meanScale[4 * i + 3] * meanScale[4 * i + 3];
      const lastX = (-f * Math.min(limitX, Math.max(-limitX, tx / tz))) / tz;
      const lastY = (-f * Math.min(limitY, Math.max(-limitY, ty / tz))) / tz;
      const a = s2 * ((f / tz) ** 2 + lastX * lastX) + SPEC.COV_DILATION;
      const c = s2 * ((f / tz) ** 2 + lastY * lastY) + SPEC.COV_DILATION;
      const r = RADIUS * Math.sqrt(Math.max(a, c));
      const u = (f * tx) / tz + cx;
      const v = (f * ty) / tz + cy;
      left = Math.min(left, u - r);
      top = Math.min(top, v - r);
      right = Math.max(right, u + r);
      bottom = Math.max(bottom, v + r);
      half = Math.max(half, r);
    }
    sortByDepth();
    for (let i = 0; i < N; i++) orderValues[i] = order[i];
    upload(orderTexture, W_TEX, ROWS, gl.RED, orderValues);
    const x0 = Math.max(0, Math.floor(left));
    const y0 = Math.max(0, Math.floor(top));
    const x1 = Math.min(width, Math.ceil(right) + 1);
    const y1 = Math.min(height, Math.ceil(bottom) + 1);
    return { box: x1 > x0 && y1 > y0 ? [x0, y0, x1 - x0, y1 - y0] : null, half };
  }

  // ---- the camera (pghm/render/framing.py, pghm/splat/camera.py) ------------------------------
  const FOV_Y = (data.camera.fov_y * Math.PI) / 180;
  const [LOW, HIGH] = data.rest_box;
  function framing(aspect) {
    const target = [0, 1, 2].map((i) => (LOW[i] + HIGH[i]) / 2);
    const half = [0, 1, 2].map((i) => (HIGH[i] - LOW[i]) / 2);
    const tangent = Math.tan(FOV_Y / 2) * data.camera.body_fill;
    return { target, distance: Math.max(half[1] / tangent, half[0] / (tangent * aspect)) + half[2] };
  }
  const sub = (p, q) => [p[0] - q[0], p[1] - q[1], p[2] - q[2]];
  const cross = (p, q) => [p[1] * q[2] - p[2] * q[1], p[2] * q[0] - p[0] * q[2], p[0] * q[1] - p[1] * q[0]];
  const dot = (p, q) => p[0] * q[0] + p[1] * q[1] + p[2] * q[2];
  const unit = (p) => { const n = Math.hypot(p[0], p[1], p[2]); return [p[0] / n, p[1] / n, p[2] / n]; };

  // Camera.look_at: rows right, down, forward; world_to_camera kept as float32, as pghm's is.
  function lookAt(eye, target, up, width, height) {
    const forward = unit(sub(target, eye));
    const right = unit(cross(forward, up));
    const down = cross(forward, right);
    const rows = [right, down, forward];
    const matrix = [];
    for (const row of rows) matrix.push(row[0], row[1], row[2], -dot(row, eye));
    matrix.push(0, 0, 0, 1);
    const focal = (0.5 * height) / Math.tan(FOV_Y / 2);
    return { worldToCamera: matrix.map(Math.fround), focal, principal: [width / 2, height / 2], eye };
  }

  const view = { yaw: 0, pitch: 0, zoom: 1, pan: [0, 0, 0] };
  function camera(frame, width, height) {
    const frameOf = framing(width / height);
    const root = roots.subarray(3 * frame, 3 * frame + 3);
    const rest = data.rest_root;
    const target = [
      frameOf.target[0] + (root[0] - rest[0]) + view.pan[0],
      frameOf.target[1] + view.pan[1],
      frameOf.target[2] + (root[2] - rest[2]) + view.pan[2],
    ];
    const yaw = (view.yaw * Math.PI) / 180;
    const pitch = (view.pitch * Math.PI) / 180;
    const distance = frameOf.distance * view.zoom;
    const direction = [Math.cos(pitch) * Math.sin(yaw), Math.sin(pitch), Math.cos(pitch) * Math.cos(yaw)];
    const eye = [0, 1, 2].map((i) => target[i] + distance * direction[i]);
    return { ...lookAt(eye, target, [0, 1, 0], width, height), distance, target };
  }

  // ---- drawing --------------------------------------------------------------------------------
  function ensureAccum(width, height) {
    if (accum && accum.width === width && accum.height === height) return;
    if (accum) {
      gl.deleteTexture(accum.texture);
      gl.deleteFramebuffer(accum.framebuffer);
    }
    const made = texture(width, height, ACCUM[0], ACCUM[1]);
    const framebuffer = gl.createFramebuffer();
    gl.bindFramebuffer(gl.FRAMEBUFFER, framebuffer);
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, made, 0);
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    accum = { texture: made, framebuffer, width, height };
  }

  const state = { frame: 0, skinned: -1, sortedKey: "", extent: null, playing: true, speed: 1, time: 0, background: [1, 1, 1] };
  state.dirty = true;

  function draw() {
    const width = canvas.width;
    const height = canvas.height;
    if (state.skinned !== state.frame) {
      skin(state.frame);
      state.skinned = state.frame;
      state.sortedKey = "";
    }
    const cam = camera(state.frame, width, height);
    const key = `${cam.worldToCamera.join(",")}/${width}x${height}`;
    if (key !== state.sortedKey) {
      state.extent = sortAndMeasure(cam, width, height);
      state.sortedKey = key;
    }
    const { box, half } = state.extent;
    // The background everywhere; the sprites only inside their box (cleared, drawn, composited).
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    gl.viewport(0, 0, width, height);
    gl.clearColor(...state.background, 1);
    gl.clear(gl.COLOR_BUFFER_BIT);
    state.dirty = false;
    if (box === null) return;
    // GL rows run bottom-up; the accumulation holds image row 0 in GL row 0 (no flip), the
    // window shows it flipped, so its scissor box is mirrored.
    ensureAccum(width, height);
    gl.enable(gl.SCISSOR_TEST);
    gl.bindFramebuffer(gl.FRAMEBUFFER, accum.framebuffer);
    gl.scissor(box[0], box[1], box[2], box[3]);
    gl.clearColor(0, 0, 0, 0);
    gl.clear(gl.COLOR_BUFFER_BIT);
    gl.enable(gl.BLEND);
    gl.blendFunc(gl.ONE_MINUS_DST_ALPHA, gl.ONE);
    // Points (one vertex a sprite) when every square fits; GL clips a point by its centre, so the
    // viewport reaches `guard` pixels past the image (the scissor keeps the image).
    const usePoints = 2 * half <= LARGEST_POINT;
    const sprite = usePoints ? points : quads;
    const guard = usePoints ? Math.ceil(half) : 0;
    gl.viewport(-guard, -guard, width + 2 * guard, height + 2 * guard);
    gl.useProgram(sprite.program);
    const u = sprite.uniforms;
    const m = cam.worldToCamera;
    // GLSL matrices are column-major: column c holds row entries m[4 r + c].
    gl.uniformMatrix4fv(u.world_to_camera, false, [0, 1, 2, 3].flatMap((c) => [m[c], m[4 + c], m[8 + c], m[12 + c]]));
    gl.uniform2f(u.focal, cam.focal, cam.focal);
    gl.uniform2f(u.principal, cam.principal[0], cam.principal[1]);
    gl.uniform2f(u.image_size, width, height);
    gl.uniform1f(u.guard, guard);
    [meanScaleTexture, colorOpacityTexture, orderTexture].forEach((made, unitIndex) => {
      gl.activeTexture(gl.TEXTURE0 + unitIndex);
      gl.bindTexture(gl.TEXTURE_2D, made);
    });
    gl.uniform1i(u.mean_scale, 0);
    gl.uniform1i(u.color_opacity, 1);
    gl.uniform1i(u.draw_order, 2);
    gl.bindVertexArray(emptyVao);
    if (usePoints) gl.drawArrays(gl.POINTS, 0, N);
    else gl.drawArrays(gl.TRIANGLES, 0, 6 * N); // PGHM_TRIANGLES: six vertices a sprite, no instancing
    gl.disable(gl.BLEND);
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    gl.viewport(0, 0, width, height);
    gl.scissor(box[0], height - box[1] - box[3], box[2], box[3]);
    gl.useProgram(composite.program);
    gl.activeTexture(gl.TEXTURE0);
    gl.bindTexture(gl.TEXTURE_2D, accum.texture);
    gl.uniform1i(composite.uniforms.accum, 0);
    gl.uniform3f(composite.uniforms.background, ...state.background);
    gl.uniform1i(composite.uniforms.flip_y, 1);
    gl.uniform1i(composite.uniforms.opaque, 1);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
    gl.disable(gl.SCISSOR_TEST);
    gl.bindVertexArray(null);
    state.primitive = usePoints ? "points" : "quads";
  }

  // ---- controls -------------------------------------------------------------------------------
  const ui = {
    play: document.getElementById("play"),
    scrub: document.getElementById("scrub"),
    frame: document.getElementById("frame"),
    speed: document.getElementById("speed"),
    background: document.getElementById("background"),
    reset: document.getElementById("reset"),
    png: document.getElementById("png"),
  };
  ui.scrub.max = String(F - 1);

  function seek(frame) {
    state.frame = ((Math.round(frame) % F) + F) % F;
    state.time = state.frame / data.fps;
    state.dirty = true;
    ui.scrub.value = String(state.frame);
    ui.frame.textContent = `${state.frame + 1} / ${F}`;
  }
  function setPlaying(playing) {
    state.playing = playing && F > 1;
    ui.play.textContent = state.playing ? "pause" : "play";
  }
  function resetView() {
    Object.assign(view, { yaw: 0, pitch: 0, zoom: 1, pan: [0, 0, 0] });
    state.dirty = true;
  }
  ui.play.addEventListener("click", () => setPlaying(!state.playing));
  ui.scrub.addEventListener("input", () => { setPlaying(false); seek(Number(ui.scrub.value)); });
  ui.speed.addEventListener("change", () => { state.speed = Number(ui.speed.value); });
  ui.background.addEventListener("input", () => {
    const hex = ui.background.value;
    state.background = [1, 3, 5].map((i) => parseInt(hex.slice(i, i + 2), 16) / 255);
    document.body.style.background = hex;
    state.dirty = true;
  });
  ui.reset.addEventListener("click", resetView);
  ui.png.addEventListener("click", () => {
    if (state.dirty) draw();
    canvas.toBlob((blob) => {
      const link = document.createElement("a");
      link.href = URL.createObjectURL(blob);
      link.download = `${data.title}_frame${state.frame}.png`;
      link.click();
      setTimeout(() => URL.revokeObjectURL(link.href), 1000);
    }, "image/png");
  });
  window.addEventListener("keydown", (event) => {
    if (event.target instanceof HTMLInputElement || event.target instanceof HTMLSelectElement) return;
    if (event.key === " ") { setPlaying(!state.playing); event.preventDefault(); }
    else if (event.key === "ArrowRight") { setPlaying(false); seek(state.frame + FRAME_KEY_STEP); }
    else if (event.key === "ArrowLeft") { setPlaying(false); seek(state.frame - FRAME_KEY_STEP); }
    else if (event.key === "r") resetView();
  });

  // Mouse and touch: one pointer orbits (the right button or shift pans), two pinch to zoom and pan.
  const pointers = new Map();
  function pan(dx, dy) {
    const cam = camera(state.frame, canvas.width, canvas.height);
    const metresPerPixel = cam.distance / cam.focal;
    const m = cam.worldToCamera;
    const right = [m[0], m[1], m[2]];
    const down = [m[4], m[5], m[6]];
    for (let i = 0; i < 3; i++) view.pan[i] -= (dx * right[i] + dy * down[i]) * metresPerPixel;
  }
  function zoomBy(factor) {
    view.zoom = Math.min(ZOOM_RANGE[1], Math.max(ZOOM_RANGE[0], view.zoom * factor));
  }
  canvas.addEventListener("contextmenu", (event) => event.preventDefault());
  canvas.addEventListener("pointerdown", (event) => {
    canvas.setPointerCapture(event.pointerId);
    pointers.set(event.pointerId, { x: event.clientX, y: event.clientY, pan: event.button === 2 || event.shiftKey });
  });
  canvas.addEventListener("pointermove", (event) => {
    const last = pointers.get(event.pointerId);
    if (!last) return;
    const scale = window.devicePixelRatio || 1;
    const dx = (event.clientX - last.x) * scale;
    const dy = (event.clientY - last.y) * scale;
    if (pointers.size === 1) {
      if (last.pan) pan(dx, dy);
      else {
        view.yaw -= dx * ORBIT_DEGREES_PER_PIXEL;
        view.pitch = Math.max(-PITCH_LIMIT, Math.min(PITCH_LIMIT, view.pitch + dy * ORBIT_DEGREES_PER_PIXEL));
      }
    } else if (pointers.size === 2) {
      const [other] = [...pointers].filter(([id]) => id !== event.pointerId).map(([, p]) => p);
      const before = Math.hypot(last.x - other.x, last.y - other.y);
      const after = Math.hypot(event.clientX - other.x, event.clientY - other.y);
      if (before > 0 && after > 0) zoomBy(before / after);
      pan(dx / 2, dy / 2);
    }
    last.x = event.clientX;
    last.y = event.clientY;
    state.dirty = true;
  });
  for (const name of ["pointerup", "pointercancel"]) {
    canvas.addEventListener(name, (event) => pointers.delete(event.pointerId));
  }
  canvas.addEventListener("wheel", (event) => {
    zoomBy(Math.exp(event.deltaY * ZOOM_PER_WHEEL_UNIT));
    state.dirty = true;
    event.preventDefault();
  }, { passive: false });
  canvas.addEventListener("dblclick", resetView);

  // ---- the loop -------------------------------------------------------------------------------
  let fixedSize = false;
  function fitCanvas() {
    if (fixedSize) return;
    const scale = window.devicePixelRatio || 1;
    const width = Math.max(1, Math.round(canvas.clientWidth * scale));
    const height = Math.max(1, Math.round(canvas.clientHeight * scale));
    if (canvas.width !== width || canvas.height !== height) {
      canvas.width = width;
      canvas.height = height;
      state.dirty = true;
    }
  }
  let last = null;
  function tick(now) {
    if (last !== null && state.playing) {
      state.time += ((now - last) / 1000) * state.speed;
      const frame = Math.round(state.time * data.fps) % F; // frame_at: the nearest frame, looping
      if (frame !== state.frame) {
        state.frame = frame;
        ui.scrub.value = String(frame);
        ui.frame.textContent = `${frame + 1} / ${F}`;
        state.dirty = true;
      }
    }
    last = now;
    fitCanvas();
    if (state.dirty) draw();
    requestAnimationFrame(tick);
  }

  // The first frame now, before the first animation frame, so that it shows as soon as it can.
  fitCanvas();
  seek(0);
  setPlaying(true);
  draw();
  const probe = new Uint8Array(4);
  gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, probe); // waits for the frame to finish
  const firstFrameMs = performance.now();
  requestAnimationFrame(tick);

  // A small API for scripts and tests: pose the player, draw now, read the pixels back.
  window.pghmPlayer = {
    frames: F,
    fps: data.fps,
    gaussians: N,
    firstFrameMs,
    accumulation: ACCUM[0] === gl.RGBA32F ? "rgba32f" : ACCUM[0] === gl.RGBA16F ? "rgba16f" : "rgba8",
    get primitive() { return state.primitive; }, // what the last draw drew sprites as: "points" or "quads"
    seek(frame) { setPlaying(false); seek(frame); },
    play() { setPlaying(true); },
    setView(options) { Object.assign(view, options); state.dirty = true; },
    setBackground(rgb) { state.background = rgb.slice(0, 3); state.dirty = true; },
    resize(width, height) {
      fixedSize = true;
      canvas.width = width;
      canvas.height = height;
      state.dirty = true;
    },
    // Draw now (`times` times, to time the pipeline without a wait between draws), wait for the
    // GPU, and return the milliseconds per draw.
    render(times = 1) {
      const start = performance.now();
      for (let i = 0; i < times; i++) {
        state.dirty = true;
        draw();
      }
      gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, probe);
      return (performance.now() - start) / times;
    },
    // (H, W, 4) RGBA bytes, the top row first (GL reads the bottom row first).
    pixels() {
      const width = canvas.width;
      const height = canvas.height;
      const raw = new Uint8Array(width * height * 4);
      gl.readPixels(0, 0, width, height, gl.RGBA, gl.UNSIGNED_BYTE, raw);
      const out = new Uint8Array(raw.length);
      const row = width * 4;
      for (let y = 0; y < height; y++) out.set(raw.subarray((height - 1 - y) * row, (height - y) * row), y * row);
      return { width, height, data: out };
    },
  };
})();
