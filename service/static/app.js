// forest render jobs: the page.  Plain JavaScript over the service's HTTP API.
//   #            the job table (filter by state and name), the submit form, the workers
//   #job=<id>    one job: live preview, frame grid, flip-book, downloads, log
"use strict";

const $ = (sel, root = document) => root.querySelector(sel);
const TERMINAL = new Set(["succeeded", "failed", "canceled"]);
const STATES = ["queued", "running", "succeeded", "failed", "canceled"];
const ASSET_EXT = /\.(png|jpe?g|tiff?|exr|hdr|ply|obj|stl|glb|gltf|off)$/i;
let token = localStorage.getItem("forest-token") || "";

// ---- helpers -------------------------------------------------------------------------
function authHeaders(extra = {}) { return token ? { ...extra, Authorization: `Bearer ${token}` } : extra; }
function withToken(url) {
  if (!url || !token) return url;
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
  if (r.status === 204) return null;
  const type = r.headers.get("content-type") || "";
  const data = type.includes("json") ? await r.json() : await r.text();
  if (!r.ok) throw new Error(data && data.detail ? (typeof data.detail === "string" ? data.detail : JSON.stringify(data.detail)) : r.statusText);
  return data;
}
function el(tag, attrs = {}, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (v === undefined || v === null || v === false) continue;
    if (k === "dataset") Object.assign(e.dataset, v);
    else if (k.startsWith("on")) e.addEventListener(k.slice(2), v);
    else if (k in e && typeof v !== "string") e[k] = v;
    else e.setAttribute(k, v === true ? "" : v);
  }
  for (const c of children.flat()) if (c !== null && c !== undefined) e.append(c instanceof Node ? c : String(c));
  return e;
}
function duration(s) {
  if (s === null || s === undefined) return "—";
  s = Math.max(0, Math.round(s));
  if (s < 60) return `${s} s`;
  if (s < 3600) return `${Math.floor(s / 60)} min ${String(s % 60).padStart(2, "0")} s`;
  return `${Math.floor(s / 3600)} h ${String(Math.floor(s / 60) % 60).padStart(2, "0")} min`;
}
function clock(t) {
  if (!t) return "—";
  const d = new Date(t * 1000), now = new Date();
  const hm = d.toLocaleTimeString([], { hour: "2-digit", minute: "2-digit", second: "2-digit" });
  return d.toDateString() === now.toDateString() ? hm : `${d.toLocaleDateString()} ${hm}`;
}
function elapsed(job) {
  if (!job.started) return null;
  return (job.finished || Date.now() / 1000) - job.started;
}
function pct(x) { return `${Math.round((x || 0) * 100)}%`; }
function jobLabel(job) { return job.name || `${job.kind} ${job.id.slice(0, 8)}`; }

// Replace a table's rows, keeping each row element whose content did not change (no flicker,
// and an element someone is about to click stays the same element).
function keepRows(tbody, rows) {
  const old = [...tbody.children];
  const same = rows.length === old.length && rows.every((r, i) => r.outerHTML === old[i].outerHTML);
  if (!same) tbody.replaceChildren(...rows.map((r, i) => (old[i] && old[i].outerHTML === r.outerHTML ? old[i] : r)));
}

// ---- views -----------------------------------------------------------------------------
let current = null;  // the open job page: {id, job, source, frames, ...}
function route() {
  const m = location.hash.match(/^#job=([0-9a-f]{32})$/);
  if (m) { openJob(m[1]); } else { closeJob(); }
  $("#list-view").hidden = !!m;
  $("#job-view").hidden = !m;
}
window.addEventListener("hashchange", route);

// ---- submit form -------------------------------------------------------------------------
const form = $("#job-form");
function syncKind() { form.dataset.kind = $("#kind").value; }
$("#kind").addEventListener("change", syncKind);
syncKind();

$("#token").value = token;
$("#token").addEventListener("change", () => {
  token = $("#token").value.trim();
  localStorage.setItem("forest-token", token);
  refreshList();
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

// The server's limits on what a job may ask for (GET /health: limits); the form's inputs follow them.
let limits = null;
function applyLimits(l) {
  if (!l) return;
  limits = l;
  const set = (sel, max) => { if (max) { $(sel).max = String(max); $(sel).title = `at most ${max.toLocaleString()} on this server`; } };
  set("#width", l.max_width);
  set("#height", l.max_height);
  set("#spp", l.max_spp);
  set("#count", l.max_trees);
  set("#iterations", l.max_iterations);
  // Uploads: the file size, the decode budget of an image and the memory its check may use.
  const mib = n => `${(n / 2 ** 20).toFixed(0)} MiB`;
  const files = `at most ${mib(l.max_upload_bytes)} a file on this server; an image at most ` +
    `${mib(l.max_decoded_bytes)} decoded (checked in ${mib(l.max_check_memory_bytes)})`;
  for (const sel of ["#folder-files", "#asset-files"]) $(sel).title = files;
}

async function upload(entries) {
  // entries: [{file, path}]; every path keeps its folders (maps/height.png)
  const status = $("#asset-status");
  const done = [], failed = [];
  for (const { file, path } of entries) {
    if (limits && file.size > limits.max_upload_bytes) {
      failed.push(`${path}: ${(file.size / 2 ** 20).toFixed(1)} MiB is over this server's upload limit of ` +
        `${(limits.max_upload_bytes / 2 ** 20).toFixed(1)} MiB`);
      continue;
    }
    status.textContent = `uploading ${path}…`;
    try {
      const url = "/assets/" + path.split("/").map(encodeURIComponent).join("/");
      await api("PUT", url, file, { "Content-Type": "application/octet-stream" });
      done.push(path);
    } catch (e) { failed.push(`${path}: ${e.message}`); }
  }
  status.textContent = (done.length ? `uploaded ${done.length} file(s): ${done.join(", ")}` : "") +
    (failed.length ? ` — refused: ${failed.join("; ")}` : "");
  status.dataset.uploaded = String(done.length);
  loadAssets();
}

$("#folder-files").addEventListener("change", async (ev) => {
  const files = [...ev.target.files];
  // A scene folder (a .toml at its top) uploads what is inside it, as the config names it
  // (maps/…); any other folder keeps its own name in the path (a "maps" folder → maps/…).
  const rel = f => f.webkitRelativePath || f.name;
  const scenes = files.filter(f => rel(f).split("/").length === 2 && f.name.endsWith(".toml"));
  const strip = scenes.length > 0;
  if (scenes.length && !$("#config").value.trim()) $("#config").value = await scenes[0].text();
  const entries = files
    .filter(f => ASSET_EXT.test(f.name))
    .map(f => ({ file: f, path: strip ? rel(f).split("/").slice(1).join("/") : rel(f) }));
  await upload(entries);
});
$("#asset-files").addEventListener("change", (ev) => upload([...ev.target.files].map(f => ({ file: f, path: f.name }))));

function intField(id) { const v = $(id).value.trim(); return v === "" ? undefined : parseInt(v, 10); }

form.addEventListener("submit", async (ev) => {
  ev.preventDefault();
  const kind = $("#kind").value;
  const settings = {};
  for (const [k, id] of [["width", "#width"], ["height", "#height"], ["spp", "#spp"], ["count", "#count"]]) {
    const v = intField(id); if (v !== undefined) settings[k] = v;
  }
  if ($("#variant").value) settings.variant = $("#variant").value;
  if ($("#preview").checked) settings.preview = true;
  if (["flythrough", "rib", "usd"].includes(kind) && $("#frames").value.trim()) settings.frames = $("#frames").value.trim();
  if (kind === "flythrough") { const n = intField("#frames-per-task"); if (n !== undefined) settings.frames_per_task = n; }
  if (kind === "rib" && $("#renderman22").checked) settings.renderman22 = true;
  if (kind === "match") {
    if ($("#reference").value) settings.reference = $("#reference").value;
    if ($("#mask").value) settings.mask = $("#mask").value;
    const it = intField("#iterations"); if (it !== undefined) settings.iterations = it;
    const res = intField("#resolution"); if (res !== undefined) settings.resolution = res;
  }
  const body = { kind, config: $("#config").value, settings, priority: intField("#priority") || 0 };
  if ($("#name").value.trim()) body.name = $("#name").value.trim();
  const status = $("#submit-status");
  status.textContent = "submitting…";
  $("#submit").disabled = true;
  try {
    const key = (crypto.randomUUID && crypto.randomUUID()) || String(Math.random()).slice(2);
    const job = await api("POST", "/jobs", body, { "Idempotency-Key": key });
    status.textContent = `queued ${jobLabel(job)}`;
    location.hash = `#job=${job.id}`;
  } catch (e) {
    status.textContent = `error: ${e.message}`;
  } finally {
    $("#submit").disabled = false;
  }
});

async function loadAssets() {
  try {
    const assets = await api("GET", "/assets");
    const images = assets.filter(a => a.kind === "image").map(a => a.name);
    for (const [id, none] of [["#reference", null], ["#mask", "none (automatic regions)"]]) {
      const sel = $(id), cur = sel.value;
      const options = images.map(name => el("option", { value: name }, name));
      sel.replaceChildren(...(none ? [el("option", { value: "" }, none)] : []), ...options);
      if (cur) sel.value = cur;
    }
  } catch (e) { /* shown elsewhere */ }
}

// ---- the job table ---------------------------------------------------------------------------
$("#filter-state").addEventListener("change", () => refreshList());
let nameTimer = null;
$("#filter-name").addEventListener("input", () => { clearTimeout(nameTimer); nameTimer = setTimeout(refreshList, 200); });

function jobRow(job) {
  const frames = job.frames_total ? ` · ${job.frames_done}/${job.frames_total} frames` : "";
  return el("tr", { dataset: { id: job.id, state: job.state } },
    el("td", {}, el("a", { href: `#job=${job.id}`, class: "job-link" }, jobLabel(job))),
    el("td", {}, job.kind),
    el("td", {}, el("span", { class: "state" }, job.state)),
    el("td", { class: "progress" }, el("progress", { max: 1, value: job.progress }), ` ${pct(job.progress)}${frames}`),
    el("td", {}, clock(job.created)),
    el("td", {}, duration(elapsed(job))),
    el("td", {}, TERMINAL.has(job.state) ? "—" : duration(job.eta_s)),
    el("td", {}, job.trees === null || job.trees === undefined ? "—" : job.trees.toLocaleString()));
}

async function refreshList() {
  try {
    const params = new URLSearchParams({ limit: "100" });
    if ($("#filter-state").value) params.set("state", $("#filter-state").value);
    if ($("#filter-name").value.trim()) params.set("name", $("#filter-name").value.trim());
    const list = await api("GET", `/jobs?${params}`);
    keepRows($("#jobs tbody"), list.jobs.map(jobRow));
    $("#no-jobs").hidden = list.jobs.length > 0;
    const c = list.counts;
    $("#counts").textContent = STATES.map(s => `${c[s]} ${s}`).join(" · ") + ` = ${c.total} job${c.total === 1 ? "" : "s"}`;
  } catch (e) { $("#counts").textContent = e.message; }
}

// What a worker renders with when a job names no variant, and its GPU (the reason is the cell's tooltip).
function rendersWith(w) {
  if (!w.variant) return "—";
  const gpu = w.gpu ? ` · ${w.gpu}` + (w.gpu_memory_mib ? ` ${(w.gpu_memory_mib / 1024).toFixed(0)} GiB` : "") : "";
  return w.variant + gpu;
}

async function refreshWorkers() {
  try {
    const h = await api("GET", "/health");
    const room = h.limits && h.limits.worker_memory_bytes;
    $("#health").textContent = `${h.executor} executor · ${h.workers} worker(s)` +
      (room ? ` · ${(room / 2 ** 30).toFixed(1)} GiB for a render` : "");
    applyLimits(h.limits);
    for (const opt of $("#kind").options) opt.disabled = !h.capabilities[opt.value];
    const { workers } = await api("GET", "/workers");
    keepRows($("#workers tbody"), workers.map(w => el("tr", { dataset: { state: w.state } },
      el("td", {}, w.name),
      el("td", {}, el("span", { class: "state" }, w.state)),
      el("td", {}, w.job_id
        ? el("a", { href: `#job=${w.job_id}` }, `${w.job_name || w.job_id.slice(0, 8)} · task ${w.task}` +
            (w.frame !== null && w.frame !== undefined ? ` · frame ${w.frame}` : "") +
            (w.progress !== null && w.progress !== undefined ? ` · ${pct(w.progress)}` : ""))
        : "—"),
      el("td", {}, String(w.tasks_done)),
      el("td", { title: w.variant_reason || null }, rendersWith(w)),
      el("td", { class: "muted" }, [w.host, w.pid ? `pid ${w.pid}` : null].filter(Boolean).join(" · ") || "—"))));
  } catch (e) { $("#health").textContent = e.message; }
}

// ---- one job ----------------------------------------------------------------------------------
function closeJob() {
  if (!current) return;
  if (current.source) current.source.close();
  clearInterval(current.tick);
  stopFlip();
  current = null;
}

async function openJob(id) {
  if (current && current.id === id) return;
  closeJob();
  current = { id, job: null, source: null, frames: [], selected: null, timer: null, tick: null, flip: [] };
  for (const sel of ["#job-title", "#job-message", "#job-error", "#pass-label", "#frames-label", "#job-log", "#downloads"]) $(sel).replaceChildren();
  $("#job-preview").hidden = true;
  $("#job-preview").removeAttribute("src");
  $("#frame-grid").replaceChildren();
  $("#frame-detail").hidden = true;
  $("#flipbook-panel").hidden = true;
  try {
    renderJob(await api("GET", `/jobs/${id}`));
  } catch (e) { $("#job-title").textContent = e.message; return; }
  refreshFrames();
  refreshLog();
  refreshDownloads();
  current.tick = setInterval(() => current && current.job && renderFacts(current.job), 1000);
  if (!TERMINAL.has(current.job.state)) watch(id);
}

function renderJob(job) {
  if (!current || current.id !== job.id) return;
  current.job = { ...(current.job || {}), ...job };
  job = current.job;
  document.title = `forest · ${jobLabel(job)}`;
  $("#job-view").dataset.state = job.state;
  $("#job-title").textContent = `${jobLabel(job)} `;
  $("#job-title").append(el("span", { class: "muted" }, `${job.kind} · ${job.id.slice(0, 8)}`));
  $("#job-state").textContent = job.state;
  $("#job-bar").value = job.progress || 0;
  $("#job-message").textContent = job.message || "";
  $("#job-error").textContent = job.error || "";
  $("#job-cancel").disabled = TERMINAL.has(job.state);
  $("#job-resume").hidden = !(job.state === "failed" || job.state === "canceled");
  $("#job-delete").hidden = !TERMINAL.has(job.state);
  if (job.preview && !current.livePreview) showPreview(job.preview);
  renderFacts(job);
}

function renderFacts(job) {
  const s = job.settings || {};
  const facts = [
    ["submitted", clock(job.created)],
    ["started", clock(job.started)],
    [TERMINAL.has(job.state) ? "took" : "elapsed", duration(elapsed(job))],
    ["ETA", TERMINAL.has(job.state) ? "—" : duration(job.eta_s)],
    ["progress", pct(job.progress)],
    ["frames", job.frames_total ? `${job.frames_done} / ${job.frames_total}` : "—"],
    ["trees", job.trees === null || job.trees === undefined ? "—" : job.trees.toLocaleString()],
    ["image", s.width ? `${s.width}×${s.height} · ${s.spp} spp${s.preview ? " · preview" : ""}${s.variant ? " · " + s.variant : ""}` : "—"],
  ];
  $("#job-facts").replaceChildren(...facts.flatMap(([k, v]) => [el("dt", {}, k), el("dd", { dataset: { fact: k } }, v)]));
}

function showPreview(url, label) {
  const img = $("#job-preview");
  const src = withToken(url);
  if (img.dataset.src !== src) { img.dataset.src = src; img.src = src; }
  img.hidden = false;
  if (label) $("#pass-label").textContent = label;
}

function watch(id) {
  if (!window.EventSource) return;
  const es = new EventSource(withToken(`/jobs/${id}/events`));
  current.source = es;
  const on = (type, fn) => es.addEventListener(type, (ev) => {
    if (!current || current.id !== id) return;
    let d; try { d = JSON.parse(ev.data); } catch { return; }
    fn(d, ev);
  });
  on("snapshot", d => renderJob(d));
  on("progress", (d, ev) => {
    const patch = { progress: d.progress, message: d.message };
    if (d.eta_s !== undefined && current.job.tasks && current.job.tasks.length === 1) patch.eta_s = d.eta_s;
    renderJob({ ...current.job, ...patch });
    if (d.trees !== undefined) renderJob({ ...current.job, trees: d.trees });
    if (d.preview) {
      current.livePreview = true;
      const pass = d.passes_done ? `${d.frame !== undefined ? `frame ${d.frame} · ` : ""}pass ${d.passes_done}/${d.passes_total}` : d.message;
      showPreview(`/jobs/${id}/files/${d.preview}?v=${ev.lastEventId}`, pass);
      $("#job-preview").dataset.passes = String(d.passes_done || 0);
    }
    if (d.frame !== undefined) scheduleFrames();
  });
  for (const t of ["frame", "task", "retry", "cancel"]) on(t, () => { scheduleFrames(); scheduleJob(); });
  on("state", d => {
    renderJob({ ...current.job, state: d.state, progress: d.progress });
    scheduleJob();
    if (TERMINAL.has(d.state)) {
      es.close();
      current.source = null;
      api("GET", `/jobs/${id}`).then(job => { renderJob(job); refreshDownloads(); }).catch(() => {});
      refreshFrames();
      refreshLog();
    }
  });
  es.onerror = () => { if (es.readyState === EventSource.CLOSED && current && current.source === es) current.source = null; };
}

let jobTimer = null;
function scheduleJob() {
  if (jobTimer) return;
  jobTimer = setTimeout(async () => {
    jobTimer = null;
    if (!current) return;
    try { renderJob(await api("GET", `/jobs/${current.id}`)); } catch (e) { /* transient */ }
  }, 300);
}

$("#job-cancel").addEventListener("click", () => act("cancel"));
$("#job-resume").addEventListener("click", () => act("resume"));
$("#job-delete").addEventListener("click", async () => {
  if (!current || !confirm(`Delete ${jobLabel(current.job)} and its outputs?`)) return;
  try { await api("DELETE", `/jobs/${current.id}`); location.hash = "#"; } catch (e) { $("#job-error").textContent = e.message; }
});
async function act(what, url) {
  if (!current) return;
  try {
    const job = await api("POST", url || `/jobs/${current.id}/${what}`);
    renderJob(job);
    scheduleFrames();
    if (current && !current.source && !TERMINAL.has(job.state)) watch(current.id);  // it runs again: follow it
  } catch (e) { $("#job-error").textContent = e.message; }
}

// ---- frame grid --------------------------------------------------------------------------------
function scheduleFrames() {
  if (!current || current.timer) return;
  current.timer = setTimeout(() => { if (current) { current.timer = null; refreshFrames(); } }, 400);
}

async function refreshFrames() {
  if (!current) return;
  const id = current.id;
  let frames;
  try { frames = await api("GET", `/jobs/${id}/frames`); } catch (e) { return; }
  if (!current || current.id !== id) return;
  current.frames = frames;
  const job = current.job;
  const grid = $("#frame-grid");
  if (!frames.length) {
    // not a frame job (match, export): its tasks
    $("#frames-label").textContent = "";
    grid.replaceChildren(...(job.tasks || []).map(t => el("button", {
      type: "button", class: "cell task", dataset: { state: t.state, task: String(t.index) },
      title: t.error || t.message, onclick: () => selectTask(t.index) },
      el("span", { class: "label" }, `task ${t.index} · ${t.state}`))));
    return;
  }
  const done = frames.filter(f => f.state === "done").length;
  $("#frames-label").textContent = `${done} of ${frames.length} done`;
  const cells = new Map([...grid.querySelectorAll(".cell[data-frame]")].map(c => [c.dataset.frame, c]));
  const order = [];
  for (const f of frames) {
    let cell = cells.get(String(f.frame));
    if (!cell) {
      cell = el("button", { type: "button", class: "cell", dataset: { frame: String(f.frame) }, onclick: () => selectFrame(f.frame) },
        el("img", { alt: `frame ${f.frame}`, loading: "lazy" }), el("span", { class: "label" }, String(f.frame)));
    }
    cell.dataset.state = f.state;
    cell.title = `frame ${f.frame}: ${f.state}` + (f.seconds !== null ? ` in ${f.seconds.toFixed(2)} s` : "") + (f.resumed ? " (kept from disk)" : "") + (f.error ? ` — ${f.error}` : "");
    const img = cell.querySelector("img");
    const src = withToken(f.thumb || f.preview || "");
    if (src && img.dataset.src !== src) { img.dataset.src = src; img.src = src; }
    img.hidden = !src;
    order.push(cell);
  }
  grid.replaceChildren(...order);
  if (current.selected !== null) selectFrame(current.selected, false);
  updateFlip();
}

async function selectFrame(frame, showLog = true) {
  if (!current) return;
  current.selected = frame;
  const f = current.frames.find(x => x.frame === frame);
  if (!f) return;
  for (const c of $("#frame-grid").querySelectorAll(".cell")) c.classList.toggle("selected", c.dataset.frame === String(frame));
  const task = (current.job.tasks || []).find(t => t.index === f.task) || {};
  const shown = JSON.stringify([f, task.state, task.worker, task.frames]);
  if (!showLog && $("#frame-detail").dataset.shown === shown) return;  // unchanged: keep its elements
  $("#frame-detail").dataset.shown = shown;
  $("#frame-detail").hidden = false;
  $("#frame-title").textContent = `Frame ${frame}`;
  $("#frame-facts").replaceChildren(...[
    ["state", f.state + (f.resumed ? " (kept from disk)" : "")],
    ["task", `${f.task}${task.frames && task.frames.length > 1 ? ` (frames ${task.frames[0]}–${task.frames[task.frames.length - 1]})` : ""}`],
    ["attempt", String(f.attempt)],
    ["time", f.seconds !== null ? duration(f.seconds) + ` (${f.seconds.toFixed(2)} s)` : "—"],
    ["worker", task.worker || "—"],
  ].flatMap(([k, v]) => [el("dt", {}, k), el("dd", {}, v)]));
  const links = [];
  if (f.exr) links.push(el("a", { href: withToken(f.exr), download: `frame_${String(frame).padStart(4, "0")}.exr`, class: "download exr" }, "EXR"));
  if (f.png) links.push(el("a", { href: withToken(f.png), download: "", target: "_blank", class: "download png" }, "PNG"));
  links.push(el("button", { type: "button", class: "requeue", disabled: !TERMINAL.has(task.state),
    onclick: () => act("requeue", `/jobs/${current.id}/frames/${frame}/requeue`) }, "Render again"));
  links.push(el("button", { type: "button", class: "quiet", onclick: () => showTaskLog(f.task) }, "Task log"));
  $("#frame-links").replaceChildren(...links);
  $("#frame-error").textContent = f.error || "";
  if (showLog) $("#frame-log").hidden = true;
}

function selectTask(index) {
  const t = (current.job.tasks || []).find(x => x.index === index);
  if (!t) return;
  current.selected = null;
  $("#frame-detail").dataset.shown = "";
  $("#frame-detail").hidden = false;
  $("#frame-title").textContent = `Task ${index}`;
  $("#frame-facts").replaceChildren(...[
    ["state", t.state], ["attempt", `${t.attempt} of ${t.max_attempts}`], ["time", duration(t.seconds)], ["worker", t.worker || "—"],
  ].flatMap(([k, v]) => [el("dt", {}, k), el("dd", {}, v)]));
  $("#frame-links").replaceChildren(
    el("button", { type: "button", disabled: !TERMINAL.has(t.state), onclick: () => act("requeue", `/jobs/${current.id}/tasks/${index}/requeue`) }, "Run again"),
    el("button", { type: "button", class: "quiet", onclick: () => showTaskLog(index) }, "Task log"));
  $("#frame-error").textContent = t.error || "";
}

async function showTaskLog(index) {
  const pre = $("#frame-log");
  try { pre.textContent = (await api("GET", `/jobs/${current.id}/tasks/${index}/log`)) || "(empty)"; }
  catch (e) { pre.textContent = e.message; }
  pre.hidden = false;
}

// ---- flip-book -------------------------------------------------------------------------------
function updateFlip() {
  const done = current.frames.filter(f => f.state === "done" && f.png);
  $("#flipbook-panel").hidden = done.length < 2;
  const urls = done.map(f => withToken(f.png));
  if (urls.join() === current.flip.map(x => x.url).join()) return;
  current.flip = done.map((f, i) => {
    const old = current.flip.find(x => x.url === urls[i]);
    if (old) return old;
    const img = new Image(); img.src = urls[i];  // preloaded, so playback does not wait on the network
    return { frame: f.frame, url: urls[i], img };
  });
  const pos = $("#flip-pos");
  pos.max = String(Math.max(0, current.flip.length - 1));
  showFlip(Math.min(parseInt(pos.value, 10) || 0, current.flip.length - 1));
}
function showFlip(i) {
  if (!current || !current.flip.length) return;
  const item = current.flip[Math.max(0, i)];
  $("#flip-pos").value = String(i);
  $("#flip-image").src = item.url;
  $("#flip-image").dataset.frame = String(item.frame);
  $("#flip-label").textContent = `frame ${item.frame} (${i + 1} of ${current.flip.length})`;
}
let flipTimer = null;
function stopFlip() { clearInterval(flipTimer); flipTimer = null; $("#flip-play").textContent = "Play"; }
$("#flip-play").addEventListener("click", () => {
  if (flipTimer) { stopFlip(); return; }
  const fps = parseInt($("#flip-fps").value, 10) || 24;
  $("#flip-play").textContent = "Pause";
  flipTimer = setInterval(() => {
    if (!current || !current.flip.length) { stopFlip(); return; }
    showFlip((parseInt($("#flip-pos").value, 10) + 1) % current.flip.length);
  }, 1000 / fps);
});
$("#flip-fps").addEventListener("change", () => { if (flipTimer) { stopFlip(); $("#flip-play").click(); } });
$("#flip-pos").addEventListener("input", () => showFlip(parseInt($("#flip-pos").value, 10)));

// ---- downloads and log -----------------------------------------------------------------------
async function refreshDownloads() {
  if (!current) return;
  const job = current.job, list = $("#downloads");
  if (job.state !== "succeeded") {
    const partial = job.frames_done > 0 ? [el("li", {}, el("a", { href: withToken(`/jobs/${job.id}/outputs.zip?ext=exr`) }, "EXR frames finished so far (zip)"))] : [];
    list.replaceChildren(...partial, el("li", { class: "muted" }, "Every output is offered here once the job has succeeded; finished frames are in the frame grid."));
    return;
  }
  try {
    const res = await api("GET", `/jobs/${job.id}/result`);
    const files = el("details", {}, el("summary", {}, `every file (${res.outputs.length})`),
      el("ul", {}, ...res.outputs.map(o => el("li", {}, el("a", { href: withToken(o.url), download: "" }, o.path), ` ${(o.bytes / 1024).toFixed(1)} KiB`))));
    list.replaceChildren(...res.downloads.map(d => el("li", {}, el("a", { href: withToken(d.url), class: "download" }, d.label))), el("li", {}, files));
  } catch (e) { list.replaceChildren(el("li", { class: "muted" }, e.message)); }
}

async function refreshLog() {
  if (!current) return;
  try { $("#job-log").textContent = (await api("GET", `/jobs/${current.id}/log`)) || "(empty)"; } catch (e) { $("#job-log").textContent = e.message; }
}
$("#log-refresh").addEventListener("click", refreshLog);

// ---- start ---------------------------------------------------------------------------------------
(async function init() {
  try {
    examples = await api("GET", "/examples");
    for (const ex of examples) $("#example").append(el("option", { value: ex.name }, ex.name));
  } catch (e) { /* no examples */ }
  loadAssets();
  route();
  await Promise.all([refreshList(), refreshWorkers()]);
  setInterval(() => { if (!current) refreshList(); }, 1500);
  setInterval(refreshWorkers, 2000);
})();
