// A small WebGL point-cloud viewer: coloured points, orbit, pan and zoom by mouse and touch.
//
// Points are in the camera frame the service returns (x right, y down, z forward, metres),
// so the first view looks out of the camera that took the photo. Hand-written rather than a
// 3D library: one draw call of GL points is all it needs, and the page stays a few files
// served by the service itself, with nothing to fetch or build.
"use strict";

class CloudViewer {
  constructor(canvas) {
    this.canvas = canvas;
    const gl = canvas.getContext("webgl", { antialias: true });
    if (!gl) throw new Error("this browser has no WebGL: the point cloud cannot be drawn");
    this.gl = gl;
    this.program = this.#link(
      `attribute vec3 position; attribute vec3 colour;
       uniform mat4 transform; uniform float size; varying vec3 tint;
       void main() { gl_Position = transform * vec4(position, 1.0); gl_PointSize = size; tint = colour; }`,
      `precision mediump float; varying vec3 tint;
       void main() { gl_FragColor = vec4(tint, 1.0); }`,
    );
    this.positionBuffer = gl.createBuffer();
    this.colourBuffer = gl.createBuffer();
    this.count = 0;
    this.pointSize = 3;
    this.centre = [0, 0, 1];
    this.radius = 1;
    this.reset();
    this.#listen();
    new ResizeObserver(() => this.draw()).observe(canvas);
  }

  // Positions (x, y, z floats) and colours (r, g, b bytes), one triple per point.
  setPoints(positions, colours) {
    this.#upload(positions, colours);
    // Orbit about the middle of the cloud; frame it from the camera's own position.
    const middle = [0, 1, 2].map((axis) => median(positions, axis));
    this.centre = middle;
    this.radius = Math.max(0.1, Math.hypot(...middle));
    this.reset();
  }

  // A live cloud's next frame: the points change, the view the user has orbited to stays.
  updatePoints(positions, colours) {
    if (!this.count) return this.setPoints(positions, colours);
    this.#upload(positions, colours);
    this.draw();
  }

  #upload(positions, colours) {
    const gl = this.gl;
    this.count = positions.length / 3;
    gl.bindBuffer(gl.ARRAY_BUFFER, this.positionBuffer);
    gl.bufferData(gl.ARRAY_BUFFER, positions, gl.DYNAMIC_DRAW);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.colourBuffer);
    gl.bufferData(gl.ARRAY_BUFFER, colours, gl.DYNAMIC_DRAW);
  }

  // The view from the camera that took the photo.
  reset() {
    this.yaw = 0;
    this.pitch = 0;
    this.distance = this.radius;
    this.target = [...this.centre];
    this.draw();
  }

  setPointSize(size) {
    this.pointSize = size;
    this.draw();
  }

  draw() {
    const gl = this.gl;
    const ratio = window.devicePixelRatio || 1;
    const width = Math.max(1, Math.round(this.canvas.clientWidth * ratio));
    const height = Math.max(1, Math.round(this.canvas.clientHeight * ratio));
    if (this.canvas.width !== width || this.canvas.height !== height) {
      this.canvas.width = width;
      this.canvas.height = height;
    }
    gl.viewport(0, 0, width, height);
    gl.clearColor(0.07, 0.08, 0.1, 1);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    if (!this.count) return;
    gl.enable(gl.DEPTH_TEST);
    gl.useProgram(this.program);
    const transform = multiply(perspective(0.9, width / height, 0.01, 1000), this.#view());
    gl.uniformMatrix4fv(gl.getUniformLocation(this.program, "transform"), false, transform);
    gl.uniform1f(gl.getUniformLocation(this.program, "size"), this.pointSize * ratio);
    this.#attribute("position", this.positionBuffer, 3, gl.FLOAT, false);
    this.#attribute("colour", this.colourBuffer, 3, gl.UNSIGNED_BYTE, true);
    gl.drawArrays(gl.POINTS, 0, this.count);
  }

  // The eye orbits the target; yaw 0, pitch 0 puts it where the photo was taken from.
  #view() {
    const eye = [
      this.target[0] - this.distance * Math.sin(this.yaw) * Math.cos(this.pitch),
      this.target[1] + this.distance * Math.sin(this.pitch),
      this.target[2] - this.distance * Math.cos(this.yaw) * Math.cos(this.pitch),
    ];
    return lookAt(eye, this.target, [0, -1, 0]); // y points down in the camera frame
  }

  #pan(dx, dy) {
    // Move the target in the view plane, in proportion to the distance: the cloud follows the finger.
    const scale = (this.distance * 1.8) / this.canvas.clientHeight;
    const right = [Math.cos(this.yaw), 0, -Math.sin(this.yaw)];
    const up = [
      Math.sin(this.yaw) * Math.sin(this.pitch),
      -Math.cos(this.pitch),
      Math.cos(this.yaw) * Math.sin(this.pitch),
    ];
    for (let i = 0; i < 3; i++) this.target[i] -= (right[i] * dx - up[i] * dy) * scale;
  }

  #listen() {
    const pointers = new Map();
    let pinch = 0;
    const canvas = this.canvas;
    canvas.style.touchAction = "none";
    canvas.addEventListener("contextmenu", (event) => event.preventDefault());
    canvas.addEventListener("pointerdown", (event) => {
      canvas.setPointerCapture(event.pointerId);
      pointers.set(event.pointerId, { x: event.clientX, y: event.clientY, button: event.button, shift: event.shiftKey });
      pinch = 0;
    });
    const release = (event) => {
      pointers.delete(event.pointerId);
      pinch = 0;
    };
    canvas.addEventListener("pointerup", release);
    canvas.addEventListener("pointercancel", release);
    canvas.addEventListener("pointermove", (event) => {
      const last = pointers.get(event.pointerId);
      if (!last) return;
      const dx = event.clientX - last.x;
      const dy = event.clientY - last.y;
      last.x = event.clientX;
      last.y = event.clientY;
      if (pointers.size === 2) {
        const [a, b] = [...pointers.values()];
        const spread = Math.hypot(a.x - b.x, a.y - b.y);
        if (pinch) this.distance = clamp(this.distance * (pinch / spread), 0.05, 500);
        pinch = spread;
        this.#pan(dx / 2, dy / 2);
      } else if (last.button === 2 || last.shift) {
        this.#pan(dx, dy);
      } else {
        this.yaw += dx * 0.005;
        this.pitch = clamp(this.pitch + dy * 0.005, -1.5, 1.5);
      }
      this.draw();
    });
    canvas.addEventListener(
      "wheel",
      (event) => {
        event.preventDefault();
        this.distance = clamp(this.distance * Math.exp(event.deltaY * 0.001), 0.05, 500);
        this.draw();
      },
      { passive: false },
    );
  }

  #attribute(name, buffer, size, type, normalised) {
    const gl = this.gl;
    const location = gl.getAttribLocation(this.program, name);
    gl.bindBuffer(gl.ARRAY_BUFFER, buffer);
    gl.enableVertexAttribArray(location);
    gl.vertexAttribPointer(location, size, type, normalised, 0, 0);
  }

  #link(vertexSource, fragmentSource) {
    const gl = this.gl;
    const program = gl.createProgram();
    for (const [type, source] of [[gl.VERTEX_SHADER, vertexSource], [gl.FRAGMENT_SHADER, fragmentSource]]) {
      const shader = gl.createShader(type);
      gl.shaderSource(shader, source);
      gl.compileShader(shader);
      if (!gl.getShaderParameter(shader, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(shader));
      gl.attachShader(program, shader);
    }
    gl.linkProgram(program);
    if (!gl.getProgramParameter(program, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(program));
    return program;
  }
}

// Reads the binary little-endian PLY the service writes (float x, y, z; uchar red, green, blue),
// and any other binary little-endian vertex layout with those properties.
function parsePly(buffer) {
  const bytes = new Uint8Array(buffer);
  const marker = "end_header\n";
  let end = -1;
  for (let i = 0; i < Math.min(bytes.length, 4096) && end < 0; i++) {
    if (String.fromCharCode(...bytes.subarray(i, i + marker.length)) === marker) end = i + marker.length;
  }
  if (end < 0) throw new Error("the point cloud is not a PLY file");
  const header = new TextDecoder().decode(bytes.subarray(0, end)).split("\n");
  if (!header.includes("format binary_little_endian 1.0")) throw new Error("the PLY is not binary little-endian");
  const sizes = { float: 4, float32: 4, uchar: 1, uint8: 1, double: 8, int: 4, uint: 4, short: 2, ushort: 2 };
  let count = 0;
  const properties = [];
  for (const line of header) {
    const words = line.trim().split(/\s+/);
    if (words[0] === "element" && words[1] === "vertex") count = Number(words[2]);
    if (words[0] === "property") properties.push({ type: words[1], name: words[2] });
  }
  let stride = 0;
  const offsets = {};
  for (const { type, name } of properties) {
    offsets[name] = { offset: stride, type };
    stride += sizes[type];
  }
  const view = new DataView(buffer, end);
  const positions = new Float32Array(count * 3);
  const colours = new Uint8Array(count * 3);
  ["x", "y", "z"].forEach((axis, k) => {
    for (let i = 0; i < count; i++) positions[i * 3 + k] = view.getFloat32(i * stride + offsets[axis].offset, true);
  });
  ["red", "green", "blue"].forEach((channel, k) => {
    for (let i = 0; i < count; i++) colours[i * 3 + k] = view.getUint8(i * stride + offsets[channel].offset);
  });
  return { positions, colours, count };
}

function median(values, axis) {
  const picked = [];
  const step = Math.max(1, Math.floor(values.length / 3 / 5000)); // a sample is plenty
  for (let i = axis; i < values.length; i += 3 * step) picked.push(values[i]);
  picked.sort((a, b) => a - b);
  return picked.length ? picked[Math.floor(picked.length / 2)] : 0;
}

function clamp(value, low, high) {
  return Math.min(high, Math.max(low, value));
}

function perspective(fovY, aspect, near, far) {
  const f = 1 / Math.tan(fovY / 2);
  const d = 1 / (near - far);
  return new Float32Array([f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) * d, -1, 0, 0, 2 * far * near * d, 0]);
}

function lookAt(eye, target, up) {
  const z = normalise(eye.map((e, i) => e - target[i]));
  const x = normalise(cross(up, z));
  const y = cross(z, x);
  const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  return new Float32Array([
    x[0], y[0], z[0], 0, x[1], y[1], z[1], 0, x[2], y[2], z[2], 0, -dot(x, eye), -dot(y, eye), -dot(z, eye), 1,
  ]);
}

function multiply(a, b) {
  const out = new Float32Array(16);
  for (let col = 0; col < 4; col++) {
    for (let row = 0; row < 4; row++) {
      let sum = 0;
      for (let k = 0; k < 4; k++) sum += a[k * 4 + row] * b[col * 4 + k];
      out[col * 4 + row] = sum;
    }
  }
  return out;
}

function cross(a, b) {
  return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
}

function normalise(v) {
  const length = Math.hypot(...v) || 1;
  return v.map((c) => c / length);
}
