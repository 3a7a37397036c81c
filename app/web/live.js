// Live mode: the webcam's frames over WebSocket /v1/stream, its depth and point cloud back for each.
//
// The page sends JPEGs at the camera's rate, holding one back only while the socket is still sending
// the last; the service keeps the freshest frame it holds and answers that, counting those it skipped. The model, focal length and stride controls change the open
// stream with a JSON message. Uses page.js's API, $, say and fail.
"use strict";

const LIVE_FPS = 30;
const LIVE_JPEG_QUALITY = 0.85;

class LiveStream {
  constructor() {
    this.video = $("camera");
    this.grab = document.createElement("canvas");
    this.viewer = null;
    this.sent = 0; // frames sent
    this.lastSeq = 0; // the newest frame answered or refused: every frame up to it gets no other answer
    this.encoding = false;
    this.heldBack = 0; // frames the camera gave while two were unanswered
    this.sentAt = new Map();
    this.answers = []; // arrival times of the last answers, for the rate
    this.latencies = [];
    this.range = null; // the depth colours' range in metres, adapting slowly so colours do not flicker
    this.pending = null; // a header whose payloads are still to come
    this.stopped = false;
    window.liveStats = { answered: 0, fps: 0, latencyMs: 0, skipped: 0, heldBack: 0, errors: 0, serviceMs: 0, drawMs: 0 };
  }

  async start() {
    const media = await navigator.mediaDevices.getUserMedia({ video: { width: 640, height: 480 }, audio: false });
    this.video.srcObject = media;
    await this.video.play();
    const base = API || location.origin;
    const url = new URL("/v1/stream", base.replace(/^http/, "ws"));
    const options = { output: "both", depth_encoding: "raw16", cloud_encoding: "raw", ...liveOptions() };
    for (const [name, value] of Object.entries(options)) if (value !== null) url.searchParams.set(name, value);
    this.socket = new WebSocket(url);
    this.socket.binaryType = "arraybuffer";
    this.socket.onmessage = (event) => this.#receive(event.data);
    this.socket.onclose = (event) => {
      if (!this.stopped) {
        fail(`The stream closed: ${event.reason || `code ${event.code}`}.`);
        endLive();
      }
      this.stop();
    };
    await new Promise((resolve, reject) => {
      this.socket.onopen = resolve;
      this.socket.onerror = () => reject(new Error("the service refused the stream, or cannot be reached"));
    });
    $("live-view").hidden = false;
    liveViewer = liveViewer || new CloudViewer($("live-cloud")); // one viewer for the canvas, however often live starts
    this.viewer = liveViewer;
    this.timer = setInterval(() => this.#capture(), 1000 / LIVE_FPS);
  }

  change(options) {
    if (this.socket && this.socket.readyState === WebSocket.OPEN) this.socket.send(JSON.stringify(options));
  }

  stop() {
    this.stopped = true;
    clearInterval(this.timer);
    if (this.socket && this.socket.readyState <= WebSocket.OPEN) this.socket.close(1000, "stopped");
    const media = this.video.srcObject;
    if (media) media.getTracks().forEach((track) => track.stop());
    this.video.srcObject = null;
  }

  #capture() {
    if (this.socket.readyState !== WebSocket.OPEN || !this.video.videoWidth) return;
    // Every camera frame goes out as it comes, so the service always answers the freshest; only a frame
    // the socket has not yet sent the last one for (a slow link) is held back here.
    if (this.encoding || this.socket.bufferedAmount > 0) {
      this.heldBack++;
      return;
    }
    this.encoding = true;
    const capturedAt = performance.now();
    this.grab.width = this.video.videoWidth;
    this.grab.height = this.video.videoHeight;
    this.grab.getContext("2d").drawImage(this.video, 0, 0);
    this.grab.toBlob(
      (blob) => {
        this.encoding = false;
        if (!blob || this.socket.readyState !== WebSocket.OPEN) return;
        this.sentAt.set(++this.sent, capturedAt); // the service numbers frames 1, 2, ... as they arrive
        this.socket.send(blob);
      },
      "image/jpeg",
      LIVE_JPEG_QUALITY,
    );
  }

  #receive(data) {
    if (typeof data === "string") {
      const header = JSON.parse(data);
      if (header.type === "frame") {
        this.pending = { header, payloads: [] };
      } else if (header.type === "error") {
        if (header.seq !== null) this.lastSeq = Math.max(this.lastSeq, header.seq);
        window.liveStats.errors++;
        say(`The service refused a ${header.seq === null ? "change" : "frame"}: ${header.detail}`);
      }
      return;
    }
    const pending = this.pending;
    pending.payloads.push(data);
    if (pending.payloads.length === pending.header.payloads.length) {
      this.pending = null;
      this.#show(pending.header, pending.payloads);
    }
  }

  #show(header, payloads) {
    const now = performance.now();
    this.lastSeq = Math.max(this.lastSeq, header.seq);
    this.latencies = [...this.latencies.slice(-29), now - this.sentAt.get(header.seq)];
    for (const seq of this.sentAt.keys()) if (seq <= header.seq) this.sentAt.delete(seq);
    this.answers = [...this.answers.filter((t) => now - t < 2000), now];
    header.payloads.forEach((entry, i) => {
      if (entry.kind === "depth") this.#depth(entry, payloads[i]);
      else this.#cloud(entry, payloads[i]);
    });
    const drawn = performance.now();
    const stats = window.liveStats;
    Object.assign(stats, {
      answered: stats.answered + 1,
      fps: this.answers.length > 1 ? ((this.answers.length - 1) * 1000) / (now - this.answers[0]) : 0,
      latencyMs: middle(this.latencies),
      skipped: header.skipped,
      heldBack: this.heldBack,
      serviceMs: Object.values(header.stages_ms).reduce((a, b) => a + b, 0) + header.queued_ms,
      drawMs: drawn - now,
    });
    $("live-stats").textContent =
      `${stats.fps.toFixed(1)} frames/s · latency ${stats.latencyMs.toFixed(0)} ms · ` +
      `${stats.skipped} skipped by the service, ${stats.heldBack} held back · ` +
      `${header.model} ${header.version}, fx ${header.intrinsics.fx.toFixed(1)} (${header.intrinsics_source}) · ` +
      `inference ${header.stages_ms.inference.toFixed(0)} ms`;
  }

  #depth(entry, buffer) {
    const mm = new Uint16Array(buffer);
    const sample = [];
    for (let i = 0; i < mm.length; i += 97) if (mm[i]) sample.push(mm[i]);
    sample.sort((a, b) => a - b);
    if (sample.length) {
      const now = [sample[Math.floor(sample.length * 0.02)], sample[Math.floor(sample.length * 0.98)]];
      this.range = this.range ? this.range.map((v, i) => 0.8 * v + 0.2 * now[i]) : now;
    }
    const canvas = $("live-depth");
    canvas.width = entry.width;
    canvas.height = entry.height;
    const context = canvas.getContext("2d");
    const image = context.createImageData(entry.width, entry.height);
    const pixels = new Uint32Array(image.data.buffer);
    const [lo, hi] = this.range || [0, 1];
    const scale = (RAMP.length - 1) / Math.max(1, hi - lo);
    for (let i = 0; i < mm.length; i++) {
      pixels[i] = mm[i] ? RAMP[Math.min(RAMP.length - 1, Math.max(0, Math.round((mm[i] - lo) * scale)))] : OPAQUE_BLACK;
    }
    context.putImageData(image, 0, 0);
    $("live-depth-caption").textContent = `Depth, ${(lo / 1000).toFixed(2)}–${(hi / 1000).toFixed(2)} m (near blue, far red)`;
  }

  #cloud(entry, buffer) {
    const positions = new Float32Array(buffer, 0, entry.points * 3);
    const colours = new Uint8Array(buffer, entry.points * 12, entry.points * 3);
    this.viewer.pointSize = Number($("point-size").value);
    this.viewer.updatePoints(positions, colours);
  }
}

function middle(values) {
  const sorted = [...values].sort((a, b) => a - b);
  return sorted.length ? sorted[Math.floor(sorted.length / 2)] : 0;
}

// Near blue, through cyan, green and yellow, to far red: 256 colours as RGBA words (little-endian ImageData).
const OPAQUE_BLACK = 0xff000000;
const RAMP = Uint32Array.from({ length: 256 }, (_, n) => {
  const x = (n / 255) * 4;
  const stops = [[0, 0, 255], [0, 255, 255], [0, 255, 0], [255, 255, 0], [255, 0, 0]];
  const i = Math.min(3, Math.floor(x));
  const [r, g, b] = stops[i].map((v, k) => Math.round(v + (stops[i + 1][k] - v) * (x - i)));
  return (0xff000000 | (b << 16) | (g << 8) | r) >>> 0;
});

function liveOptions() {
  return { model: $("model").value || null, fx: $("fx").value ? Number($("fx").value) : null, stride: Number($("stride").value || 1) };
}

let live = null;
let liveViewer = null;

function endLive() {
  if (live) live.stop();
  live = null;
  $("live").textContent = "Live: start the camera";
}

$("live").addEventListener("click", async () => {
  if (live) {
    endLive();
    say("Live stopped.");
    return;
  }
  fail("");
  live = new LiveStream();
  $("live").textContent = "Live: stop";
  try {
    await live.start();
    say("Live: streaming the camera.");
  } catch (error) {
    endLive();
    fail(`Live mode could not start: ${error.message}`);
  }
});
for (const id of ["model", "fx", "stride"]) $(id).addEventListener("change", () => live && live.change(liveOptions()));
