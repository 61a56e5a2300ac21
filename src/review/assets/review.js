// cmsckf flight review: the page's own script (inlined next to uPlot).
//
// 1. Every JSON script element of class cmsckf-plot (the Rust side's
//    interactive.rs) is drawn with uPlot right after itself: the width follows the page, the
//    legend shows the values under the cursor, drag zooms, double-click
//    zooms out. Time plots share their cursor and their zoom; the events
//    ("markers") are vertical dashed lines, labelled in small text where
//    there is room, and named under the plot when the cursor is near one.
//    A plot with "kind": "xy" is a trajectory drawn to scale (uPlot mode 2).
// 2. Every <table class="cmsckf-timeline"> gets a <select> that shows only
//    the rows of one kind (<tr data-kind>); a click on a row with data-t
//    zooms every time plot to 5 s either side of that time.
// When done, the body's data-plots-ready attribute counts the plots drawn
// (and data-plots-failed those that could not be). This file must not hold
// the plot elements' class attribute or that attribute as markup: the SITL
// test counts both in the page.
(function () {
  "use strict";

  var HEIGHT = 300;
  var timeCharts = []; // {u, box}
  var xyCharts = []; // {u, box}
  var syncing = false; // set while one chart's zoom is copied to the others
  var ready = false; // set once every chart is drawn

  function fmt(v) {
    if (v == null || typeof v !== "number" || !isFinite(v)) return "–";
    var a = Math.abs(v);
    if (a !== 0 && (a >= 1e6 || a < 1e-3)) return v.toExponential(3);
    return String(parseFloat(v.toPrecision(5)));
  }

  function widthOf(box) {
    return Math.max(300, Math.floor(box.clientWidth || 900));
  }

  // A y axis wide enough for its longest tick label.
  function axisSize(u, values, axisIdx, cycleNum) {
    var axis = u.axes[axisIdx];
    if (cycleNum > 1 && axis._size) return axis._size; // settled
    var longest = 0;
    if (values) {
      for (var i = 0; i < values.length; i++) {
        var n = values[i] == null ? 0 : String(values[i]).length;
        if (n > longest) longest = n;
      }
    }
    return Math.max(50, Math.ceil(longest * 7 + 24));
  }

  function hexAlpha(color, alpha) {
    var m = /^#([0-9a-f]{2})([0-9a-f]{2})([0-9a-f]{2})$/i.exec(color || "");
    if (!m) return "rgba(127,127,127," + alpha + ")";
    return "rgba(" + parseInt(m[1], 16) + "," + parseInt(m[2], 16) + "," + parseInt(m[3], 16) + "," + alpha + ")";
  }

  function lineSeries(s, extra) {
    var o = {
      label: String(s.label == null ? "" : s.label),
      stroke: s.color || "#1f77b4",
      width: s.line === false ? 0 : 1.5,
      spanGaps: false,
      points: s.points || s.line === false
        ? { show: true, size: 5, width: 1, fill: s.color || "#1f77b4" }
        : { show: false }
    };
    if (s.dash) o.dash = [6, 4];
    if (s.line === false) o.paths = function () { return null; };
    for (var k in extra) o[k] = extra[k];
    return o;
  }

  // ---- markers: dashed vertical lines, small labels, names on hover ----

  function drawMarkers(markers) {
    return function (u) {
      if (!markers.length) return;
      var ctx = u.ctx, b = u.bbox;
      var px = window.devicePixelRatio || 1;
      var lastLabelEnd = -Infinity;
      ctx.save();
      ctx.beginPath();
      ctx.rect(b.left, b.top, b.width, b.height);
      ctx.clip();
      ctx.lineWidth = px;
      ctx.font = Math.round(10 * px) + "px sans-serif";
      ctx.textBaseline = "top";
      ctx.textAlign = "left";
      var i, m, x;
      ctx.setLineDash([4 * px, 4 * px]);
      for (i = 0; i < markers.length; i++) {
        m = markers[i];
        x = Math.round(u.valToPos(m.t, "x", true)) + 0.5;
        if (!(x >= b.left && x <= b.left + b.width)) continue;
        ctx.strokeStyle = m.color || "#7f7f7f";
        ctx.beginPath();
        ctx.moveTo(x, b.top);
        ctx.lineTo(x, b.top + b.height);
        ctx.stroke();
      }
      // Short labels at the top, each where it does not overlap the last.
      for (i = 0; i < markers.length; i++) {
        m = markers[i];
        x = Math.round(u.valToPos(m.t, "x", true)) + 0.5;
        if (!(x >= b.left && x <= b.left + b.width)) continue;
        var text = String(m.label == null ? "" : m.label);
        if (text.length > 28) text = text.slice(0, 27) + "…";
        if (text && x + 3 * px > lastLabelEnd) {
          var w = ctx.measureText(text).width;
          if (x + 3 * px + w <= b.left + b.width) {
            ctx.fillStyle = "rgba(255,255,255,0.75)";
            ctx.fillRect(x + 2 * px, b.top + 2 * px, w + 2 * px, 12 * px);
            ctx.fillStyle = m.color || "#7f7f7f";
            ctx.fillText(text, x + 3 * px, b.top + 3 * px);
            lastLabelEnd = x + 3 * px + w + 8 * px;
          }
        }
      }
      ctx.restore();
    };
  }

  // The markers within 6 px of the cursor, named in full under the plot.
  function noteMarkers(note, markers) {
    return function (u) {
      var left = u.cursor.left;
      if (!markers.length || left == null || left < 0) { note.textContent = ""; return; }
      var near = [];
      for (var i = 0; i < markers.length; i++) {
        var x = u.valToPos(markers[i].t, "x");
        if (Math.abs(x - left) <= 6) near.push(fmt(markers[i].t) + " s: " + markers[i].label);
      }
      note.textContent = near.join("  ·  ");
    };
  }

  // ---- time plots ----

  // A time chart's whole x range: its first and last time.
  function fullX(u) {
    var x = u.data[0];
    return x && x.length ? [x[0], x[x.length - 1]] : null;
  }

  // Copies a time chart's x range to the other time charts; a chart zoomed
  // out to its whole range (double-click) zooms the others out to theirs.
  function shareZoom(u, key) {
    if (key !== "x" || syncing || !ready) return;
    var min = u.scales.x.min, max = u.scales.x.max;
    if (min == null || max == null) return;
    var f = fullX(u);
    var out = f && min === f[0] && max === f[1];
    syncing = true;
    try {
      for (var i = 0; i < timeCharts.length; i++) {
        var v = timeCharts[i].u;
        if (v === u) continue;
        var r = out ? fullX(v) : [min, max];
        if (r && (v.scales.x.min !== r[0] || v.scales.x.max !== r[1])) v.setScale("x", { min: r[0], max: r[1] });
      }
    } finally {
      syncing = false;
    }
  }

  function timePlot(p, box, holder, note) {
    var x = p.x || [];
    var ys = p.y || [];
    var specs = p.series || [];
    var series = [{ label: p.x_label || "time (s)", value: function (u, v) { return fmt(v); } }];
    for (var i = 0; i < ys.length; i++) {
      series.push(lineSeries(specs[i] || { label: "series " + (i + 1) }, {
        value: function (u, v) { return fmt(v); }
      }));
    }
    var bands = [];
    var pb = p.bands || [];
    for (var j = 0; j < pb.length; j++) {
      var hi = pb[j].hi, lo = pb[j].lo;
      if (hi == null || lo == null || !specs[hi]) continue;
      bands.push({ series: [hi + 1, lo + 1], fill: hexAlpha(pb[j].color || specs[hi].color, 0.12) });
    }
    var markers = p.markers || [];
    var opts = {
      width: widthOf(box),
      height: HEIGHT,
      series: series,
      bands: bands,
      scales: { x: { time: false } },
      axes: [
        { label: p.x_label || "time (s)" },
        { label: p.y_label || "", size: axisSize }
      ],
      cursor: { drag: { x: true, y: false, setScale: true }, sync: { key: "cmsckf-time" } },
      hooks: {
        draw: [drawMarkers(markers)],
        setCursor: [noteMarkers(note, markers)],
        setScale: [shareZoom]
      }
    };
    var u = new uPlot(opts, [x].concat(ys), holder);
    timeCharts.push({ u: u, box: box });
  }

  // ---- trajectory (x = east, y = north), to scale ----

  function extent(arrs, ext) {
    for (var i = 0; i < arrs.length; i++) {
      var a = arrs[i] || [];
      for (var k = 0; k < a.length; k++) {
        var v = a[k];
        if (v != null && isFinite(v)) {
          if (v < ext[0]) ext[0] = v;
          if (v > ext[1]) ext[1] = v;
        }
      }
    }
    return ext;
  }

  // Ranges for x and y, around (cx, cy), with the same metres per pixel.
  function toScale(u, cx, cy, sx, sy) {
    var w = u.bbox && u.bbox.width ? u.bbox.width : u.width - 80;
    var h = u.bbox && u.bbox.height ? u.bbox.height : u.height - 60;
    var perPx = Math.max(sx / Math.max(w, 1), sy / Math.max(h, 1), 1e-9);
    return {
      x: [cx - perPx * w / 2, cx + perPx * w / 2],
      y: [cy - perPx * h / 2, cy + perPx * h / 2]
    };
  }

  function xyPlot(p, box, holder, note) {
    var specs = p.series || [];
    var ys = p.y || [];
    var perTrack = p.x && p.x.length && Array.isArray(p.x[0]);
    var ts = p.t && p.t.length && Array.isArray(p.t[0]) ? p.t : null;
    var data = [null];
    for (var i = 0; i < ys.length; i++) data.push([perTrack ? p.x[i] : p.x, ys[i]]);

    var ex = extent(perTrack ? p.x : [p.x], [Infinity, -Infinity]);
    var ey = extent(ys, [Infinity, -Infinity]);
    if (!(ex[0] <= ex[1])) ex = [0, 1];
    if (!(ey[0] <= ey[1])) ey = [0, 1];
    var full = function (u) {
      var sx = (ex[1] - ex[0]) * 1.06 || 2, sy = (ey[1] - ey[0]) * 1.06 || 2;
      return toScale(u, (ex[0] + ex[1]) / 2, (ey[0] + ey[1]) / 2, sx, sy);
    };

    // The point of series si nearest the cursor (within 25 px), or null.
    function nearest(u, si) {
      var left = u.cursor.left, top = u.cursor.top;
      var d = u.data[si];
      if (left == null || left < 0 || !d) return null;
      var best = null, bestD = 25 * 25;
      var xs = d[0], yv = d[1];
      for (var k = 0; k < yv.length; k++) {
        if (xs[k] == null || yv[k] == null) continue;
        var dx = u.valToPos(xs[k], "x") - left, dy = u.valToPos(yv[k], "y") - top;
        var dd = dx * dx + dy * dy;
        if (dd < bestD) { bestD = dd; best = k; }
      }
      return best;
    }

    var series = [{}];
    for (var j = 0; j < ys.length; j++) {
      (function (j) {
        var spec = specs[j] || { label: "track " + (j + 1) };
        var o = lineSeries(spec, {
          facets: [{ scale: "x", auto: true }, { scale: "y", auto: true }],
          value: function (u, v, si, idx) {
            if (idx == null) return "–";
            var d = u.data[si];
            var s = fmt(d[0][idx]) + ", " + fmt(d[1][idx]);
            if (ts && ts[j] && ts[j][idx] != null) s += " @ " + fmt(ts[j][idx]) + " s";
            return s;
          }
        });
        if (spec.points || spec.line === false) {
          var all = [];
          for (var k = 0; k < ys[j].length; k++) all.push(k);
          o.points.filter = function () { return all; };
        }
        series.push(o);
      })(j);
    }

    var opts = {
      mode: 2,
      width: widthOf(box),
      height: Math.max(HEIGHT, p.height || 500),
      series: series,
      scales: {
        x: { time: false, auto: true, range: function (u) { return full(u).x; } },
        y: { auto: true, range: function (u) { return full(u).y; } }
      },
      axes: [
        { label: p.x_label || "east (m)" },
        { label: p.y_label || "north (m)", size: axisSize }
      ],
      legend: { live: true },
      cursor: {
        drag: { x: true, y: true, setScale: false },
        points: { size: 8 },
        dataIdx: function (u, si) { return si === 0 ? null : nearest(u, si); }
      },
      hooks: {
        // Drag-zoom kept to scale: the dragged box, widened in one direction.
        setSelect: [function (u) {
          var s = u.select;
          if (s.width < 4 || s.height < 4) return;
          var x0 = u.posToVal(s.left, "x"), x1 = u.posToVal(s.left + s.width, "x");
          var y0 = u.posToVal(s.top + s.height, "y"), y1 = u.posToVal(s.top, "y");
          var r = toScale(u, (x0 + x1) / 2, (y0 + y1) / 2, Math.abs(x1 - x0), Math.abs(y1 - y0));
          u.batch(function () {
            u.setScale("x", { min: r.x[0], max: r.x[1] });
            u.setScale("y", { min: r.y[0], max: r.y[1] });
          });
          u.setSelect({ left: 0, top: 0, width: 0, height: 0 }, false);
        }]
      }
    };
    var u = new uPlot(opts, data, holder);
    xyCharts.push({ u: u, box: box });
  }

  // ---- one plot element ----

  function draw(el, index) {
    var box = document.createElement("div");
    box.className = "plot cmsckf-plot-box";
    el.parentNode.insertBefore(box, el.nextSibling);
    var p;
    try {
      p = JSON.parse(el.textContent);
    } catch (e) {
      box.textContent = "(a plot could not be read: " + e.message + ")";
      return false;
    }
    if (p.id) box.id = "plot-" + p.id;
    var h = document.createElement("h3");
    h.textContent = p.title || p.id || "plot " + (index + 1);
    box.appendChild(h);
    var holder = document.createElement("div");
    box.appendChild(holder);
    var note = document.createElement("div");
    note.className = "cmsckf-plot-note";
    note.style.cssText = "font-size:0.85em;color:#a33;min-height:1.3em";
    box.appendChild(note);
    var xs = p.x || [];
    if (!xs.length || !(p.y && p.y.length)) {
      holder.textContent = "(no data)";
      holder.style.color = "#777";
      return true;
    }
    try {
      if (p.kind === "xy") xyPlot(p, box, holder, note);
      else timePlot(p, box, holder, note);
      return true;
    } catch (e) {
      holder.textContent = "(this plot could not be drawn: " + e.message + ")";
      if (window.console) console.error("cmsckf plot " + (p.id || index), e);
      return false;
    }
  }

  // Zooms every time plot to [t0, t1].
  function zoomAll(t0, t1) {
    syncing = true;
    try {
      for (var i = 0; i < timeCharts.length; i++) timeCharts[i].u.setScale("x", { min: t0, max: t1 });
    } finally {
      syncing = false;
    }
  }

  // ---- the timeline ----

  function timeline(table) {
    var rows = table.querySelectorAll("tr[data-kind]");
    var kinds = {}, count = {};
    for (var i = 0; i < rows.length; i++) {
      var kind = rows[i].getAttribute("data-kind");
      kinds[kind] = true;
      count[kind] = (count[kind] || 0) + 1;
      if (rows[i].hasAttribute("data-t")) {
        rows[i].title = "zoom the plots to this time";
        rows[i].addEventListener("click", function () {
          var t = parseFloat(this.getAttribute("data-t"));
          if (!isFinite(t)) return;
          zoomAll(t - 5, t + 5);
          var sel = table.querySelectorAll("tr.cmsckf-selected");
          for (var k = 0; k < sel.length; k++) {
            sel[k].classList.remove("cmsckf-selected");
            sel[k].style.background = "";
          }
          this.classList.add("cmsckf-selected");
          this.style.background = "#dde6ff";
        });
      }
    }
    var label = document.createElement("label");
    label.className = "cmsckf-timeline-filter";
    label.style.cssText = "display:inline-block;margin:0.3em 0;font-size:0.9em";
    label.appendChild(document.createTextNode("Show: "));
    var select = document.createElement("select");
    var all = document.createElement("option");
    all.value = "";
    all.textContent = "every kind (" + rows.length + ")";
    select.appendChild(all);
    Object.keys(kinds).sort().forEach(function (kind) {
      var o = document.createElement("option");
      o.value = kind;
      o.textContent = kind + " (" + count[kind] + ")";
      select.appendChild(o);
    });
    select.addEventListener("change", function () {
      for (var j = 0; j < rows.length; j++) {
        var show = !select.value || rows[j].getAttribute("data-kind") === select.value;
        rows[j].style.display = show ? "" : "none";
      }
    });
    label.appendChild(select);
    var reset = document.createElement("button");
    reset.type = "button";
    reset.textContent = "zoom out";
    reset.style.marginLeft = "1em";
    reset.addEventListener("click", function () {
      syncing = true;
      try {
        for (var i = 0; i < timeCharts.length; i++) {
          var u = timeCharts[i].u, f = fullX(u);
          if (f) u.setScale("x", { min: f[0], max: f[1] });
        }
      } finally {
        syncing = false;
      }
    });
    label.appendChild(reset);
    table.parentNode.insertBefore(label, table);
  }

  // ---- width follows the page ----

  function resizeAll() {
    var all = timeCharts.concat(xyCharts);
    for (var i = 0; i < all.length; i++) {
      var c = all[i], w = widthOf(c.box);
      if (w !== c.u.width) {
        c.u.setSize({ width: w, height: c.u.height });
        if (c.u.mode === 2) c.u.setData(c.u.data, true); // back to scale
      }
    }
  }

  function main() {
    var els = document.querySelectorAll('script[type="application/json"].cmsckf-plot');
    var ok = 0, failed = 0;
    for (var i = 0; i < els.length; i++) {
      if (draw(els[i], i)) ok++;
      else failed++;
    }
    ready = true;
    var tables = document.querySelectorAll("table.cmsckf-timeline");
    for (var k = 0; k < tables.length; k++) timeline(tables[k]);
    var pending = null;
    window.addEventListener("resize", function () {
      if (pending) clearTimeout(pending);
      pending = setTimeout(resizeAll, 100);
    });
    // For a look from the console: the uPlot objects, and the zoom of the timeline.
    window.cmsckfReview = { timeCharts: timeCharts, xyCharts: xyCharts, zoomAll: zoomAll };
    document.body.setAttribute("data-plots-ready", String(ok));
    if (failed) document.body.setAttribute("data-plots-failed", String(failed));
  }

  if (typeof uPlot === "undefined") {
    document.addEventListener("DOMContentLoaded", function () {
      document.body.setAttribute("data-plots-failed", "uPlot missing");
    });
    return;
  }
  if (document.readyState === "loading") document.addEventListener("DOMContentLoaded", main);
  else main();
})();
