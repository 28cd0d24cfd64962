// cnc-gateway web console: live values over /api/live, and the forms that call the REST API.
// Plain JavaScript, no framework, nothing fetched from elsewhere: shop networks are offline.
"use strict";

const csrf = document.querySelector('meta[name="csrf"]').content;

// --- the REST API ----------------------------------------------------------------------------------

async function api(method, url, body, isForm) {
  const headers = { "X-CSRF-Token": csrf };
  const init = { method, headers, credentials: "same-origin" };
  if (body !== undefined) {
    if (isForm) {
      init.body = body;
    } else {
      headers["Content-Type"] = "application/json";
      init.body = JSON.stringify(body);
    }
  }
  let response;
  try {
    response = await fetch(url, init);
  } catch (err) {
    return { ok: false, text: "BadNotConnected: the gateway does not answer (" + err.message + ")" };
  }
  let data = null;
  try {
    data = await response.json();
  } catch (err) {
    data = null;
  }
  if (response.ok) return { ok: true, data };
  const e = (data && data.error) || { status: "HTTP " + response.status, reason: response.statusText };
  return { ok: false, data, text: e.status + ": " + e.reason };
}

function answer(el, result, okText) {
  if (!el) return;
  el.textContent = result.ok ? okText : result.text;
  el.className = "answer " + (result.ok ? "ok" : "refusal");
}

function enc(s) {
  return encodeURIComponent(s);
}

function encPath(path) {
  return path.split("/").map(encodeURIComponent).join("/");
}

// A value typed into a form, as the variable's or argument's type wants it (JSON types: numbers, booleans).
function parseValue(text, type) {
  const t = (type || "String").replace("[]", "");
  if (type && type.endsWith("[]")) {
    try { return JSON.parse(text); } catch (err) { return text; }
  }
  if (t === "Boolean") {
    if (/^(true|1|on|yes)$/i.test(text)) return true;
    if (/^(false|0|off|no)$/i.test(text)) return false;
    return text;
  }
  if (["String", "DateTime", "ByteString"].includes(t)) return text;
  if (text.trim() === "") return text;
  const n = Number(text);
  return Number.isNaN(n) ? text : n;
}

// --- live values -----------------------------------------------------------------------------------

const cells = new Map(); // "machine/path" -> [elements]
document.querySelectorAll("[data-var]").forEach((el) => {
  const key = el.dataset.var;
  if (!cells.has(key)) cells.set(key, []);
  cells.get(key).push(el);
});

function show(value) {
  if (value === null || value === undefined) return "";
  if (typeof value === "number") return String(Math.round(value * 1000) / 1000);
  if (Array.isArray(value)) return "[" + value.map(show).join(", ") + "]";
  return String(value);
}

function update(row) {
  const [machine, path, value, status, ts] = row;
  const els = cells.get(machine + "/" + path);
  if (!els) return;
  const quality = status.startsWith("Good") ? "good" : status.startsWith("Uncertain") ? "uncertain" : "bad";
  for (const el of els) {
    const v = el.querySelector(".v") || el;
    const text = show(value);
    if (v.textContent !== text) v.textContent = text;
    el.dataset.quality = quality;
    const q = el.querySelector(".q");
    if (q) q.textContent = status;
    const t = el.querySelector(".t");
    if (t && ts !== null) t.textContent = new Date(ts).toISOString().replace("T", " ").slice(0, 23);
  }
}

const DRIP_KEYS = ["block", "lead", "sent", "lines", "paused", "restart_block"];

// The drip-feed fields of a job record (the serial DNC transport adds them), as "block 120, lead 8.5".
function dripText(job) {
  const source = job.drip && typeof job.drip === "object" ? job.drip : job;
  const parts = DRIP_KEYS.filter((k) => source[k] !== undefined && source[k] !== null).map((k) => k + " " + source[k]);
  return parts.join(", ");
}

function onJob(job) {
  const drip = dripText(job);
  document.querySelectorAll('[data-drip="' + job.machine + '"]').forEach((el) => {
    el.textContent = job.state === "SENDING" && drip ? job.id + " " + drip : "–";
  });
  document.querySelectorAll('tr.job[data-job="' + job.id + '"]').forEach((tr) => {
    tr.dataset.state = job.state;
    const state = tr.querySelector(".state");
    if (state) {
      state.innerHTML = "<b></b>";
      state.firstChild.textContent = job.state;
    }
    const reason = tr.querySelector(".reason");
    if (reason) reason.textContent = job.reason || "";
    const progress = tr.querySelector(".progress");
    if (progress && typeof job.progress === "number") {
      progress.textContent = Math.round(job.progress) + " %" + (drip ? " · " + drip : "");
    }
  });
  const table = document.getElementById("jobs");
  if (table && !document.querySelector('tr.job[data-job="' + job.id + '"]')) scheduleReload();
}

function onAlarms(info) {
  document.querySelectorAll('[data-alarms="' + info.machine + '"]').forEach((el) => {
    el.textContent = String((info.active || []).filter((a) => a.active).length);
  });
  if (document.querySelector('[data-alarms-list="*"], [data-alarms-list="' + info.machine + '"]')) scheduleReload();
}

let reloadTimer = null;
function scheduleReload() {
  // A list that gained or lost rows is rendered again by the server (unless the user is typing in it).
  if (reloadTimer) return;
  reloadTimer = setTimeout(() => {
    reloadTimer = null;
    const active = document.activeElement;
    if (active && active.tagName === "INPUT" && active.value) return scheduleReload();
    location.reload();
  }, 300);
}

function connect(watch, delay) {
  const state = document.getElementById("live-state");
  const scheme = location.protocol === "https:" ? "wss://" : "ws://";
  const ws = new WebSocket(scheme + location.host + "/api/live");
  ws.onopen = () => {
    ws.send(JSON.stringify(watch));
    if (state) state.className = "live on";
  };
  ws.onmessage = (msg) => {
    const data = JSON.parse(msg.data);
    if (data.v) data.v.forEach(update);
    else if (data.job) onJob(data.job);
    else if (data.alarms) onAlarms(data.alarms);
    else if (data.error) console.warn("live:", data.error.status, data.error.reason);
  };
  ws.onclose = () => {
    if (state) state.className = "live off";
    setTimeout(() => connect(watch, Math.min((delay || 500) * 2, 10000)), delay || 500);
  };
}

const watch = JSON.parse(document.body.dataset.watch || "null");
if (watch) connect(watch, 500);

// --- writes, calls, alarms, jobs, certificates -----------------------------------------------------

document.querySelectorAll("form.write").forEach((form) => {
  form.addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const input = form.querySelector("input[name=value]");
    const value = parseValue(input.value, form.dataset.type);
    const url = "/api/machines/" + enc(form.dataset.machine) + "/variables/" + encPath(form.dataset.path);
    const result = await api("PUT", url, { value });
    answer(form.querySelector(".answer"), result, result.ok ? "ok: " + show(result.data.variable.value) : "");
  });
});

document.querySelectorAll("form.call").forEach((form) => {
  form.addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const args = {};
    form.querySelectorAll("input[name]").forEach((input) => {
      if (input.value !== "") args[input.name] = parseValue(input.value, input.dataset.type);
    });
    const url = "/api/machines/" + enc(form.dataset.machine) + "/methods/" + enc(form.dataset.object) + "/" +
      enc(form.dataset.name);
    const started = performance.now();
    const result = await api("POST", url, { args });
    let text = "";
    if (result.ok) {
      const outputs = Object.entries(result.data.outputs || {}).map(([k, v]) => k + " = " + show(v)).join(", ");
      text = "ok" + (outputs ? ": " + outputs : "") + " (" + Math.round(result.data.duration * 1000) + " ms)";
    } else {
      text = result.text + " (" + Math.round(performance.now() - started) + " ms)";
    }
    const el = form.querySelector(".answer");
    el.textContent = text;
    el.className = "answer " + (result.ok ? "ok" : "refusal");
  });
});

document.querySelectorAll("form.alarm-action").forEach((form) => {
  form.addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const comment = form.querySelector("input[name=comment]").value;
    const url = "/api/alarms/" + enc(form.dataset.machine) + "/" + enc(form.dataset.occurrence) + "/" +
      form.dataset.action;
    const result = await api("POST", url, { comment });
    answer(form.querySelector(".answer"), result, form.dataset.action === "acknowledge" ? "acknowledged" : "confirmed");
    if (result.ok) {
      const row = form.closest("tr");
      const cell = row && row.querySelector(".alarm-state");
      if (cell) cell.textContent = (result.data.alarm.active ? "active" : "cleared") +
        (result.data.alarm.acked ? ", acknowledged by " + result.data.alarm.acked_by : "") +
        (result.data.alarm.confirmed ? ", confirmed by " + result.data.alarm.confirmed_by : "");
    }
  });
});

document.querySelectorAll("button.job-action").forEach((button) => {
  button.addEventListener("click", async () => {
    const id = button.dataset.job;
    const action = button.dataset.action;
    const result = action === "priority"
      ? await api("PUT", "/api/jobs/" + enc(id) + "/priority", { priority: Number(button.dataset.priority) })
      : await api("POST", "/api/jobs/" + enc(id) + "/" + action);
    answer(button.parentElement.querySelector(".answer"), result, action + ": ok");
    if (result.ok) scheduleReload();
  });
});

document.querySelectorAll("button.cert-action").forEach((button) => {
  button.addEventListener("click", async () => {
    const result = await api("POST", "/api/gateway/certificates/" + enc(button.dataset.name) + "/" +
      button.dataset.action);
    answer(button.parentElement.querySelector(".answer"), result, button.dataset.action + "ed");
    if (result.ok) {
      const row = button.closest("tr");
      row.dataset.state = result.data.certificate.state;
      row.querySelector(".cert-state").innerHTML = "<b></b>";
      row.querySelector(".cert-state b").textContent = result.data.certificate.state;
      button.remove();
    }
  });
});

// Jobs: drag and drop (or choose) a program; it goes to POST /api/jobs, the FTP inbox's path.
const upload = document.getElementById("upload");
if (upload) {
  const zone = document.getElementById("dropzone");
  const out = document.getElementById("upload-answer");
  const send = async (file) => {
    const form = new FormData();
    form.append("machine", upload.querySelector("[name=machine]").value);
    form.append("priority", upload.querySelector("[name=priority]").value || "0");
    form.append("file", file, file.name);
    out.textContent = "sending " + file.name + " …";
    out.className = "answer";
    const result = await api("POST", "/api/jobs", form, true);
    out.textContent = result.ok ? result.data.message : (result.data && result.data.message) || result.text;
    out.className = "answer " + (result.ok ? "ok" : "refusal");
    if (result.ok || (result.data && result.data.job_id)) scheduleReload();
  };
  ["dragenter", "dragover"].forEach((name) => zone.addEventListener(name, (ev) => {
    ev.preventDefault();
    zone.classList.add("over");
  }));
  ["dragleave", "drop"].forEach((name) => zone.addEventListener(name, () => zone.classList.remove("over")));
  zone.addEventListener("drop", (ev) => {
    ev.preventDefault();
    const files = ev.dataTransfer && ev.dataTransfer.files;
    if (files && files.length) send(files[0]);
  });
  document.getElementById("upload-file").addEventListener("change", (ev) => {
    if (ev.target.files.length) send(ev.target.files[0]);
  });
}
