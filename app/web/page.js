// The demo page: a photo in, its depth and a 3D point cloud out, through the public API only.
//
// Every call is one any front end could make from another origin (`?api=https://host:port`
// points the page at another service). The page keeps no state on the server.
"use strict";

const API = (new URLSearchParams(location.search).get("api") || "").replace(/\/$/, "");
const TIMEOUT_MS = 120000;
const $ = (id) => document.getElementById(id);

let photo = null;
let viewer = null;
let cloudBlob = null;

function say(text) {
  $("status").textContent = text;
}

function fail(text) {
  $("error").textContent = text;
  $("error").hidden = !text;
  if (text) say("");
}

// A request to the API; a 4xx or 5xx becomes an Error with the API's own message in plain words,
// and a 503 is retried after its Retry-After, a few times, saying so.
async function call(path, options = {}, attempts = 4) {
  for (let attempt = 1; ; attempt++) {
    const abort = new AbortController();
    const timer = setTimeout(() => abort.abort(), TIMEOUT_MS);
    let response;
    try {
      response = await fetch(API + path, { ...options, signal: abort.signal });
    } catch (error) {
      throw new Error(
        error.name === "AbortError"
          ? `The service did not answer within ${TIMEOUT_MS / 1000} seconds.`
          : `The service cannot be reached (${error.message}).`,
      );
    } finally {
      clearTimeout(timer);
    }
    if (response.ok) return response;
    const message = await explain(response);
    if (response.status === 503 && attempt < attempts) {
      const wait = Number(response.headers.get("Retry-After") || "1");
      say(`The service is busy (${message}); trying again in ${wait} s.`);
      await new Promise((resolve) => setTimeout(resolve, wait * 1000));
      continue;
    }
    throw new Error(response.status === 503 ? `The service is busy: ${message}. Try again shortly.` : message);
  }
}

async function explain(response) {
  try {
    const body = await response.json();
    if (typeof body.detail === "string") return body.detail;
    if (Array.isArray(body.detail)) {
      return body.detail.map((d) => `${(d.loc || []).slice(-1)[0] || "request"}: ${d.msg}`).join("; ");
    }
    return JSON.stringify(body.detail ?? body);
  } catch {
    return `the service answered ${response.status} ${response.statusText}`;
  }
}

async function loadModels() {
  try {
    const listing = await (await call("/v1/models")).json();
    const select = $("model");
    const fallback = listing.default ? `${listing.default.name} ${listing.default.version}` : "";
    select.options[0].textContent = `the service's default${fallback ? ` (${fallback})` : ""}`;
    for (const model of listing.models) {
      select.add(new Option(`${model.name} (newest)`, model.name));
      for (const entry of model.versions) {
        const option = new Option(`${model.name} ${entry.version}${entry.refused ? " (refused)" : ""}`, `${model.name}:${entry.version}`);
        option.disabled = Boolean(entry.refused);
        select.add(option);
      }
    }
  } catch (error) {
    fail(`Could not list the models: ${error.message}`);
  }
}

function query(extra = {}) {
  const params = new URLSearchParams(extra);
  if ($("model").value) params.set("model", $("model").value);
  if ($("fx").value) params.set("fx", $("fx").value);
  const text = params.toString();
  return text ? `?${text}` : "";
}

function upload() {
  const form = new FormData();
  form.append("image", photo, photo.name || "photo");
  return { method: "POST", body: form };
}

function choose(file) {
  if (!file) return;
  photo = file;
  $("run").disabled = false;
  $("preview").src = URL.createObjectURL(file);
  run();
}

async function run() {
  if (!photo) return;
  fail("");
  $("run").disabled = true;
  say("Working: depth and point cloud…");
  try {
    const stride = $("stride").value || "1";
    const [depth, cloud] = await Promise.all([
      call(`/depth${query({ format: "colormap" })}`, upload()),
      call(`/pointcloud${query({ stride })}`, upload()),
    ]);
    $("depth").src = URL.createObjectURL(await depth.blob());
    const range = depth.headers.get("X-Depth-Range-M");
    if (range) $("depth-caption").textContent = `Depth, ${range.replace(",", "–")} m (near blue, far red)`;
    cloudBlob = await cloud.blob();
    const points = parsePly(await cloudBlob.arrayBuffer());
    $("results").hidden = false;
    viewer = viewer || new CloudViewer($("cloud"));
    viewer.setPoints(points.positions, points.colours);
    viewer.setPointSize(Number($("point-size").value));
    facts(cloud, depth, points.count);
    say("Done.");
  } catch (error) {
    fail(error.message);
  } finally {
    $("run").disabled = false;
  }
}

function facts(cloud, depth, count) {
  const timing = (response) =>
    (response.headers.get("Server-Timing") || "")
      .split(",")
      .map((part) => part.trim().match(/^(\w+);dur=([\d.]+)/))
      .filter(Boolean)
      .map(([, name, ms]) => `${name} ${Number(ms).toFixed(0)} ms`)
      .join(", ");
  const rows = {
    Model: `${cloud.headers.get("X-Model-Name")} ${cloud.headers.get("X-Model-Version")}`,
    Points: Number(count).toLocaleString("en"),
    Camera: `${cloud.headers.get("X-Intrinsics")} (fx, fy, cx, cy from ${cloud.headers.get("X-Intrinsics-Source")})`,
    "Point cloud timings": timing(cloud),
    "Depth timings": timing(depth),
  };
  const list = $("facts");
  list.replaceChildren();
  for (const [term, value] of Object.entries(rows)) {
    list.append(Object.assign(document.createElement("dt"), { textContent: term }));
    list.append(Object.assign(document.createElement("dd"), { textContent: value || "—" }));
  }
}

function save(blob, name) {
  const link = Object.assign(document.createElement("a"), { href: URL.createObjectURL(blob), download: name });
  document.body.append(link);
  link.click();
  link.remove();
}

function stem() {
  return (photo.name || "photo").replace(/\.[^.]*$/, "");
}

$("controls").addEventListener("submit", (event) => {
  event.preventDefault();
  run();
});
$("photo").addEventListener("change", (event) => choose(event.target.files[0]));
const drop = $("drop");
drop.addEventListener("dragover", (event) => {
  event.preventDefault();
  drop.classList.add("over");
});
drop.addEventListener("dragleave", () => drop.classList.remove("over"));
drop.addEventListener("drop", (event) => {
  event.preventDefault();
  drop.classList.remove("over");
  choose(event.dataTransfer.files[0]);
});
$("point-size").addEventListener("input", (event) => viewer && viewer.setPointSize(Number(event.target.value)));
$("reset-view").addEventListener("click", () => viewer && viewer.reset());
$("download-ply").addEventListener("click", () => cloudBlob && save(cloudBlob, `${stem()}.ply`));
$("download-png").addEventListener("click", async () => {
  fail("");
  try {
    save(await (await call(`/depth${query()}`, upload())).blob(), `${stem()}.depth.png`);
  } catch (error) {
    fail(error.message);
  }
});

loadModels();
