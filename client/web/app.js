// vbrender dashboard: what the pages share (no libraries, nothing from the
// network but this server).
"use strict";
var vb = {};

// GETs a JSON API; resolves with the body, rejects with an Error whose
// message is the server's ("master unreachable: ...") or the network's.
vb.get = function (url) {
  return fetch(url, { cache: "no-store" }).then(function (r) {
    return r.json().catch(function () { return {}; }).then(function (body) {
      if (!r.ok) {
        var e = new Error(body.error || ("HTTP " + r.status));
        e.status = r.status;
        throw e;
      }
      return body;
    });
  }, function (e) {
    throw new Error("dashboard unreachable: " + e.message);
  });
};

// The red line at the top: shown with a message, hidden with null.
vb.banner = function (msg) {
  var b = document.getElementById("banner");
  if (!b) return;
  b.textContent = msg || "";
  b.className = msg ? "shown" : "";
};

// An error from vb.get as the banner says it: a master or dashboard that is
// away reads "master unreachable" (the page keeps asking, and recovers).
vb.failed = function (e) {
  var m = e.message || String(e);
  if (e.status === 502 || e.status === 503 || m.indexOf("unreachable") >= 0)
    vb.banner(m.indexOf("master unreachable") === 0 ? m : "master unreachable: " + m);
  else
    vb.banner(m);
};

vb.si = function (v) {
  if (v === undefined || v === null || isNaN(v)) return "";
  var units = ["", "k", "M", "G", "T", "P"], i = 0;
  while (Math.abs(v) >= 1000 && i < units.length - 1) { v /= 1000; i++; }
  return (i ? v.toFixed(v < 10 ? 2 : v < 100 ? 1 : 0) : String(Math.round(v))) + units[i];
};

vb.dur = function (s) {
  if (s === undefined || s === null || isNaN(s) || s < 0) return "";
  if (s < 60) return s.toFixed(1) + " s";
  var m = Math.floor(s / 60), h = Math.floor(m / 60);
  if (h) return h + " h " + (m % 60) + " min";
  return m + " min " + Math.round(s % 60) + " s";
};

vb.ended = function (job) {
  return job.state === "done" || job.state === "failed" || job.state === "cancelled";
};

// How far a job is, 0..1: the master's "progress" when it gives one, else
// the larger of its layers and its samples done.
vb.fraction = function (job) {
  if (typeof job.progress === "number") return Math.min(1, Math.max(0, job.progress));
  var a = job.layers > 0 ? job.layers_done / job.layers : 0;
  var b = job.max_samples > 0 ? job.samples / job.max_samples : 0;
  return Math.min(1, Math.max(a, b, job.state === "done" ? 1 : 0));
};

vb.eta = function (job) {
  if (job.state === "running" && typeof job.eta_seconds === "number") return vb.dur(job.eta_seconds);
  var f = vb.fraction(job);
  if (job.state !== "running" || !(f > 0)) return "";
  return vb.dur(job.seconds / f - job.seconds);
};

vb.cell = function (tr, text, cls) {
  var td = document.createElement("td");
  td.textContent = text === undefined ? "" : text;
  if (cls) td.className = cls;
  tr.appendChild(td);
  return td;
};

vb.bump = function (el, name) {
  el.setAttribute(name, String(Number(el.getAttribute(name) || 0) + 1));
};

// Calls fn now and then every ms, never two at once (fn returns a promise).
vb.every = function (ms, fn) {
  function tick() {
    Promise.resolve().then(fn).catch(vb.failed).then(function () { setTimeout(tick, ms); });
  }
  tick();
};

// A line plot of pts ([x, y] pairs) on a canvas, y on a log scale when
// opts.log; axes with their ranges written at the ends.
vb.plot = function (canvas, pts, opts) {
  var c = canvas.getContext("2d"), W = canvas.width, H = canvas.height;
  var L = 60, R = 10, T = 20, B = 28;
  c.clearRect(0, 0, W, H);
  c.font = "11px sans-serif";
  c.fillStyle = "#222";
  c.fillText(opts.title, L, 13);
  c.strokeStyle = "#999";
  c.strokeRect(L, T, W - L - R, H - T - B);
  var p = pts.filter(function (q) { return isFinite(q[1]) && (!opts.log || q[1] > 0); });
  if (p.length < 2) {
    c.fillStyle = "#777";
    c.fillText(p.length ? "waiting for more points" : "no data yet", L + 10, T + 20);
    return;
  }
  var fy = opts.log ? function (v) { return Math.log10(v); } : function (v) { return v; };
  var x0 = p[0][0], x1 = p[p.length - 1][0], y0 = Infinity, y1 = -Infinity;
  p.forEach(function (q) { y0 = Math.min(y0, fy(q[1])); y1 = Math.max(y1, fy(q[1])); });
  if (x1 <= x0) x1 = x0 + 1;
  if (y1 <= y0) { y1 = y0 + 1; }
  function X(v) { return L + (v - x0) / (x1 - x0) * (W - L - R); }
  function Y(v) { return H - B - (fy(v) - y0) / (y1 - y0) * (H - T - B); }
  c.strokeStyle = opts.color || "#07a";
  c.lineWidth = 2;
  c.beginPath();
  p.forEach(function (q, i) { if (i) c.lineTo(X(q[0]), Y(q[1])); else c.moveTo(X(q[0]), Y(q[1])); });
  c.stroke();
  c.fillStyle = "#222";
  var top = opts.log ? Math.pow(10, y1) : y1, bottom = opts.log ? Math.pow(10, y0) : y0;
  c.fillText(opts.fmt(top), 2, T + 8);
  c.fillText(opts.fmt(bottom), 2, H - B);
  c.fillText(vb.dur(x0), L, H - 8);
  var right = vb.dur(x1);
  c.fillText(right, W - R - c.measureText(right).width, H - 8);
  c.fillText(opts.xlabel || "time", (W - L) / 2 + L - 12, H - 8);
};
