// forest render jobs: the page.  Plain JavaScript over the service's HTTP API.
"use strict";

const $ = (sel, root = document) => root.querySelector(sel);
const TERMINAL = new Set(["succeeded", "failed", "canceled"]);
const jobs = new Map();      // id -> {el, job, source}
let token = localStorage.getItem("forest-token") || "";

function authHeaders(extra = {}) {
  return token ? { ...extra, Authorization: `Bearer ${token}` } : extra;
}
function withToken(url) {
  if (!token) return url;
  return url + (url.includes("?") ? "&" : "?") + "access_token=" + encodeURIComponent(token);
}
async function api(method, url, body, headers = {}) {
  const opts = { method, headers: authHeaders(headers) };
  if (body !== undefined) {
    if (body instanceof Blob) { opts.body = body; }
    else { opts.body = JSON.stringify(body); opts.headers["Content-Type"] = "application/json"; }
  }
  const r = await fetch(url, opts);
  if (r.status === 401) { $("#token-box").hidden = false; throw new Error("a token is required"); }
  const type = r.headers.get("content-type") || "";
  const data = type.includes("json") ? await r.json() : await r.text();
  if (!r.ok) throw new Error((data && data.detail) ? (typeof data.detail === "string" ? data.detail : JSON.stringify(data.detail)) : r.statusText);
  return data;
}

// ---- submit form -----------------------------------------------------------
const form = $("#job-form");
function syncKind() { form.dataset.kind = $("#kind").value; }
$("#kind").addEventListener("change", syncKind);
syncKind();

$("#token").value = token;
$("#token").addEventListener("change", () => {
  token = $("#token").value.trim();
  localStorage.setItem("forest-token", token);
  refreshAll();
});

$("#config-file").addEventListener("change", async (ev) => {
  const f = ev.target.files[0];
  if (f) $("#config").value = await f.text();
});

let examples = [];
$("#example").addEventListener("change", () => {
  const ex = examples.find(e => e.name === $("#example").value);
  if (ex) $("#config").value = ex.text;
});

$("#asset-files").addEventListener("change", async (ev) => {
  const status = $("#asset-status");
  for (const f of ev.target.files) {
    status.textContent = `uploading ${f.name}…`;
    try {
      const a = await api("PUT", `/assets/${encodeURIComponent(f.name)}`, f, { "Content-Type": "application/octet-stream" });
      status.textContent = `uploaded ${a.name} (${a.kind}, ${a.bytes} bytes)`;
    } catch (e) { status.textContent = `${f.name}: ${e.message}`; }
  }
  loadAssets();
});

function intField(id) { const v = $(id).value.trim(); return v === "" ? undefined : parseInt(v, 10); }

form.addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const kind = $("#kind").value;
  const settings = {};
  for (const [k, id] of [["width", "#width"], ["height", "#height"], ["spp", "#spp"], ["count", "#count"]]) {
    const v = intField(id); if (v !== undefined) settings[k] = v;
  }
  if ($("#variant").value) settings.variant = $("#variant").value;
  if (kind === "flythrough") {
    if ($("#frames").value.trim()) settings.frames = $("#frames").value.trim();
    const fpt = intField("#frames-per-task"); if (fpt !== undefined) settings.frames_per_task = fpt;
  }
  if (kind === "match") {
    if ($("#reference").value) settings.reference = $("#reference").value;
    const it = intField("#iterations"); if (it !== undefined) settings.iterations = it;
    const res = intField("#resolution"); if (res !== undefined) settings.resolution = res;
  }
  const body = { kind, config: $("#config").value, settings, priority: intField("#priority") || 0 };
  const status = $("#submit-status");
  status.textContent = "submitting…";
  $("#submit").disabled = true;
  try {
    const key = (crypto.randomUUID && crypto.randomUUID()) || String(Math.random()).slice(2);
    const job = await api("POST", "/jobs", body, { "Idempotency-Key": key });
    status.textContent = `queued ${job.id.slice(0, 8)}`;
    upsert(job);
  } catch (e) {
    status.textContent = `error: ${e.message}`;
  } finally {
    $("#submit").disabled = false;
  }
});

// ---- job list ----------------------------------------------------------------
function upsert(job) {
  let entry = jobs.get(job.id);
  if (!entry) {
    const el = $("#job-template").content.firstElementChild.cloneNode(true);
    el.dataset.id = job.id;
    $(".cancel", el).addEventListener("click", () => act(job.id, "cancel"));
    $(".retry", el).addEventListener("click", () => act(job.id, "retry"));
    $(".show-log", el).addEventListener("click", () => toggleLog(job.id));
    const list = $("#jobs");
    list.insertBefore(el, list.firstChild);
    entry = { el, job, source: null };
    jobs.set(job.id, entry);
  }
  entry.job = { ...entry.job, ...job };
  render(entry);
  if (!TERMINAL.has(entry.job.state)) watch(entry);
}

function render(entry) {
  const { el, job } = entry;
  el.dataset.state = job.state;
  $(".kind", el).textContent = job.kind + (job.name ? ` · ${job.name}` : "");
  $(".id", el).textContent = job.id.slice(0, 8);
  $(".state", el).textContent = job.state;
  $(".bar", el).value = job.progress || 0;
  $(".message", el).textContent = `${Math.round((job.progress || 0) * 100)}% ${job.message || ""}`;
  $(".error", el).textContent = job.error || "";
  $(".cancel", el).disabled = TERMINAL.has(job.state);
  $(".retry", el).hidden = !(job.state === "failed" || job.state === "canceled");
  const res = $(".result", el);
  res.hidden = job.state !== "succeeded";
  res.href = withToken(`/jobs/${job.id}/result`);
  if (job.preview) {
    const img = $(".preview", el);
    const src = withToken(job.preview);
    if (img.dataset.src !== src) { img.dataset.src = src; img.src = src; }
    img.hidden = false;
  }
  if (job.state === "succeeded") addToGallery(job);
}

function watch(entry) {
  if (entry.source || !window.EventSource) return;
  const id = entry.job.id;
  const es = new EventSource(withToken(`/jobs/${id}/events`));
  entry.source = es;
  const onData = (ev) => {
    let d; try { d = JSON.parse(ev.data); } catch { return; }
    if (ev.type === "snapshot") { upsert(d); return; }
    const patch = {};
    if (d.progress !== undefined) patch.progress = d.progress;
    if (d.message) patch.message = d.message;
    if (d.state && ev.type === "state") patch.state = d.state;
    if (d.preview) patch.preview = `/jobs/${id}/preview?v=${ev.lastEventId}`;
    entry.job = { ...entry.job, ...patch };
    render(entry);
    if (ev.type === "state" && TERMINAL.has(d.state)) { es.close(); entry.source = null; refreshJob(id); refreshAll(); }
  };
  for (const t of ["snapshot", "state", "progress", "task", "cancel", "retry"]) es.addEventListener(t, onData);
  es.onerror = () => {
    if (es.readyState === EventSource.CLOSED) { entry.source = null; }
    refreshJob(id);
  };
}

async function refreshJob(id) {
  try {
    const job = await api("GET", `/jobs/${id}`);
    const entry = jobs.get(id);
    if (entry && TERMINAL.has(job.state) && entry.source) { entry.source.close(); entry.source = null; }
    upsert(job);
  } catch (e) { /* transient */ }
}

async function act(id, what) {
  try { upsert(await api("POST", `/jobs/${id}/${what}`)); }
  catch (e) { const entry = jobs.get(id); if (entry) $(".error", entry.el).textContent = e.message; }
}

async function toggleLog(id) {
  const entry = jobs.get(id);
  const pre = $(".log", entry.el);
  if (!pre.hidden) { pre.hidden = true; return; }
  try { pre.textContent = await api("GET", `/jobs/${id}/log`) || "(empty)"; }
  catch (e) { pre.textContent = e.message; }
  pre.hidden = false;
}

const inGallery = new Set();
async function addToGallery(job) {
  if (inGallery.has(job.id)) return;
  inGallery.add(job.id);
  try {
    const res = await api("GET", `/jobs/${job.id}/result`);
    if (!res.image) return;
    const fig = document.createElement("figure");
    fig.dataset.id = job.id;
    const img = document.createElement("img");
    img.src = withToken(res.image);
    img.alt = `result of ${job.id}`;
    const cap = document.createElement("figcaption");
    const s = job.settings || {};
    const stats = (res.stats && res.stats[0]) || {};
    const parts = [`${job.kind} ${s.width}×${s.height} ${s.spp} spp`, `${s.trees} trees`];
    const shown = { variant: "", instanced_triangles: " instanced triangles", load_seconds: " s load",
                    render_seconds: " s render", peak_memory_gb: " GB peak", seconds: " s" };
    for (const [k, suffix] of Object.entries(shown)) {
      const v = stats[k];
      if (typeof v === "number") parts.push(`${Number.isInteger(v) ? v.toLocaleString() : v.toFixed(2)}${suffix}`);
      else if (typeof v === "string") parts.push(v);
    }
    cap.textContent = parts.join(" · ");
    const a = document.createElement("a");
    a.href = img.src; a.target = "_blank"; a.appendChild(img);
    fig.append(a, cap);
    $("#gallery").prepend(fig);
  } catch (e) { inGallery.delete(job.id); }
}

// ---- periodic refresh ----------------------------------------------------------
async function loadAssets() {
  try {
    const assets = await api("GET", "/assets");
    const sel = $("#reference");
    const cur = sel.value;
    sel.innerHTML = "";
    for (const a of assets.filter(a => a.kind === "image")) {
      const o = document.createElement("option"); o.value = o.textContent = a.name; sel.appendChild(o);
    }
    if (cur) sel.value = cur;
  } catch (e) { /* shown elsewhere */ }
}

async function refreshAll() {
  try {
    const h = await api("GET", "/health");
    const c = h.counts;
    $("#health").textContent = `${h.executor} executor · ${h.workers} worker(s)`;
    $("#counts").textContent = `${c.queued} queued · ${c.running} running · ${c.succeeded} done · ${c.failed} failed`;
    for (const opt of $("#kind").options) opt.disabled = !h.capabilities[opt.value];
    const list = await api("GET", "/jobs?limit=50");
    for (const job of list.jobs.slice().reverse()) {
      const entry = jobs.get(job.id);
      if (!entry || entry.job.state !== job.state || (!entry.source && !TERMINAL.has(job.state))) upsert(job);
    }
  } catch (e) {
    $("#health").textContent = e.message;
  }
}

(async function init() {
  try {
    examples = await api("GET", "/examples");
    for (const ex of examples) {
      const o = document.createElement("option"); o.value = o.textContent = ex.name; $("#example").appendChild(o);
    }
  } catch (e) { /* no examples */ }
  loadAssets();
  await refreshAll();
  setInterval(refreshAll, 3000);
})();
