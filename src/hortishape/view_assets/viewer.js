/* hortishape's model viewer: the glue between the embedded model and plotly.js.
 *
 * The page holds the model as JSON (id "hs-data"): the mean, each mode's displacement at +1 SD
 * quantized per mode, the triangles, and per-vertex maps. The shape drawn is
 *   x = mean + sum_i b_i * sqrt(lambda_i) * phi_i,
 * with b_i the sliders in standard deviations. The state lives in the URL fragment
 * (#b=b1,b2,...&c=colouring) so that a view can be shared and scripted.
 */
(function () {
  "use strict";

  var D = JSON.parse(document.getElementById("hs-data").textContent);
  var N = D.n_vertices, K = D.modes.count, LIMIT = D.slider_limit;
  var COLOURINGS = ["shape", "displacement", "sd"].concat(D.error ? ["error"] : []);
  var status = window.hortishape = {ready: false, renders: 0, errors: [], b: null, colour: "shape"};

  function decode(item) {
    var s = atob(item.data), bytes = new Uint8Array(s.length);
    for (var i = 0; i < s.length; i++) bytes[i] = s.charCodeAt(i);
    var types = {float32: Float32Array, int16: Int16Array, int8: Int8Array, uint16: Uint16Array, uint32: Uint32Array};
    return new types[item.dtype](bytes.buffer);
  }

  var mean = decode(D.mean), modes = decode(D.modes), faces = decode(D.faces), normals = decode(D.normals);
  var scale = D.modes.scale;  // mm per quantum, per mode, at +1 SD
  var sdMap = decode(D.sd), errorMap = D.error ? decode(D.error) : null;
  var fi = new Int32Array(faces.length / 3), fj = new Int32Array(faces.length / 3), fk = new Int32Array(faces.length / 3);
  for (var t = 0; t < fi.length; t++) { fi[t] = faces[3 * t]; fj[t] = faces[3 * t + 1]; fk[t] = faces[3 * t + 2]; }

  // ---- the shape for coefficients b (in SD) ----
  function shapeOf(b) {
    var p = Float32Array.from(mean), n3 = 3 * N;
    for (var k = 0; k < K; k++) {
      if (!b[k]) continue;
      var s = b[k] * scale[k], off = k * n3;
      for (var i = 0; i < n3; i++) p[i] += s * modes[off + i];
    }
    return p;
  }

  function component(p, c) {
    var out = new Float32Array(N);
    for (var i = 0; i < N; i++) out[i] = p[3 * i + c];
    return out;
  }

  // signed displacement from the mean along the mean's outward normal, mm
  function displacement(p) {
    var d = new Float32Array(N);
    for (var i = 0; i < N; i++) {
      d[i] = ((p[3 * i] - mean[3 * i]) * normals[3 * i] + (p[3 * i + 1] - mean[3 * i + 1]) * normals[3 * i + 1] +
              (p[3 * i + 2] - mean[3 * i + 2]) * normals[3 * i + 2]) / 127;
    }
    return d;
  }

  function maxAbs(a) {
    var m = 0;
    for (var i = 0; i < a.length; i++) { var v = Math.abs(a[i]); if (v > m) m = v; }
    return m;
  }

  // ---- state <-> URL fragment ----
  function parseFragment() {
    var b = new Array(K).fill(0), colour = "shape";
    var parts = (window.location.hash || "").replace(/^#/, "").split("&");
    parts.forEach(function (part) {
      var kv = part.split("=");
      if (kv[0] === "b" && kv.length > 1) {
        kv[1].split(",").slice(0, K).forEach(function (v, k) {
          var x = parseFloat(v);
          if (isFinite(x)) b[k] = Math.max(-LIMIT, Math.min(LIMIT, x));
        });
      } else if (kv[0] === "c" && COLOURINGS.indexOf(kv[1]) >= 0) {
        colour = kv[1];
      }
    });
    return {b: b, colour: colour};
  }

  function fragmentOf(b, colour) {
    var last = -1;
    for (var k = 0; k < K; k++) if (b[k]) last = k;
    var text = "#b=" + (last < 0 ? "0" : b.slice(0, last + 1).map(function (v) {
      return String(Math.round(v * 100) / 100);
    }).join(","));
    return colour === "shape" ? text : text + "&c=" + colour;
  }

  // ---- the page ----
  var plot = document.getElementById("hs-plot");
  var b = new Array(K).fill(0), colour = "shape";
  var sliders = [], readouts = [];

  function buildSliders() {
    var box = document.getElementById("hs-sliders");
    for (var k = 0; k < K; k++) {
      var row = document.createElement("div");
      row.className = "hs-slider";
      var label = document.createElement("label");
      label.htmlFor = "hs-mode-" + (k + 1);
      label.textContent = "mode " + (k + 1);
      label.title = (100 * D.variance_ratio[k]).toFixed(1) + " % of the variance";
      var input = document.createElement("input");
      input.type = "range"; input.min = -LIMIT; input.max = LIMIT; input.step = 0.1; input.value = 0;
      input.id = "hs-mode-" + (k + 1);
      input.setAttribute("data-mode", k);
      input.addEventListener("input", onSlider);
      var out = document.createElement("output");
      out.htmlFor = input.id;
      row.appendChild(label); row.appendChild(input); row.appendChild(out);
      box.appendChild(row);
      sliders.push(input); readouts.push(out);
    }
  }

  function showState() {
    for (var k = 0; k < K; k++) {
      sliders[k].value = b[k];
      readouts[k].textContent = (b[k] >= 0 ? "+" : "") + b[k].toFixed(1);
    }
    document.getElementById("hs-colour").value = colour;
  }

  function writeFragment() {
    var text = fragmentOf(b, colour);
    if (window.location.hash === text) return;
    try { history.replaceState(null, "", text); } catch (e) { window.location.hash = text; }
  }

  var pending = false;
  function schedule() {
    if (pending) return;
    pending = true;
    window.requestAnimationFrame(function () { pending = false; draw(); });
  }

  function onSlider(ev) {
    b[+ev.target.getAttribute("data-mode")] = parseFloat(ev.target.value);
    showState(); writeFragment(); schedule();
  }

  function colouring(p) {
    var legend = {shape: "", displacement: "outward (+) / inward (-) from the mean, mm",
                  sd: "the model's SD at each point, mm", error: "geometric error of the registration, mm"};
    document.getElementById("hs-legend").textContent = legend[colour];
    if (colour === "shape") return {color: D.colour, showscale: false};
    var values, cmin, cmax, scaleName;
    if (colour === "displacement") {
      values = displacement(p);
      cmax = Math.max(maxAbs(values), 0.01); cmin = -cmax; scaleName = "RdBu";
    } else {
      values = colour === "sd" ? sdMap : errorMap;
      cmin = 0; cmax = Math.max(maxAbs(values), 1e-6); scaleName = "Viridis";
    }
    return {intensity: values, intensitymode: "vertex", colorscale: scaleName, reversescale: colour === "displacement",
            cmin: cmin, cmax: cmax, showscale: true, colorbar: {title: {text: "mm"}, len: 0.6, thickness: 14}};
  }

  function landmarkTrace(p) {
    var xs = [], ys = [], zs = [], names = [];
    D.landmarks.forEach(function (m) {
      var v = [faces[3 * m.face], faces[3 * m.face + 1], faces[3 * m.face + 2]];
      var q = [0, 1, 2].map(function (c) {
        var s = 0;
        for (var r = 0; r < 3; r++) s += m.barycentric[r] * (p[3 * v[r] + c] + D.landmark_lift * normals[3 * v[r] + c] / 127);
        return s;
      });
      xs.push(q[0]); ys.push(q[1]); zs.push(q[2]); names.push(m.name);
    });
    return {type: "scatter3d", mode: "markers+text", x: xs, y: ys, z: zs, text: names, name: "landmarks",
            textposition: "top center", marker: {size: 5, color: "#d62728", line: {color: "#ffffff", width: 1}},
            hoverinfo: "text", showlegend: false};
  }

  var CAMERAS = {
    front: {eye: {x: 0, y: -2.4, z: 0}, up: {x: 0, y: 0, z: 1}, center: {x: 0, y: 0, z: 0}},
    top: {eye: {x: 0, y: 0, z: 2.4}, up: {x: 0, y: 1, z: 0}, center: {x: 0, y: 0, z: 0}},
    iso: {eye: {x: -1.1, y: -1.95, z: 0.85}, up: {x: 0, y: 0, z: 1}, center: {x: 0, y: 0, z: 0}}
  };
  var layout = {
    margin: {l: 0, r: 0, t: 0, b: 0}, paper_bgcolor: "#ffffff", uirevision: "keep", showlegend: false,
    scene: {aspectmode: "data", camera: CAMERAS.iso, dragmode: "orbit",
            xaxis: {title: {text: "x (mm)"}}, yaxis: {title: {text: "y (mm)"}}, zaxis: {title: {text: "z (mm)"}}}
  };
  var config = {displaylogo: false, responsive: true, scrollZoom: true,
                toImageButtonOptions: {format: "png", filename: D.file_stem}};

  function draw() {
    var p = shapeOf(b);
    var mesh = Object.assign({
      type: "mesh3d", x: component(p, 0), y: component(p, 1), z: component(p, 2), i: fi, j: fj, k: fk,
      flatshading: false, hoverinfo: "skip", name: "shape",
      lighting: {ambient: 0.5, diffuse: 0.7, specular: 0.15, roughness: 0.5, fresnel: 0.05},
      lightposition: {x: 0, y: -2e5, z: 1e5}
    }, colouring(p));
    var traces = [mesh];
    if (D.landmarks.length) traces.push(landmarkTrace(p));
    status.b = b.slice(); status.colour = colour;
    return Plotly.react(plot, traces, layout, config).then(function () {
      status.renders += 1;
      status.ready = true;
      document.documentElement.setAttribute("data-renders", String(status.renders));
    });
  }

  function fromFragment() {
    var s = parseFragment();
    b = s.b; colour = s.colour;
    showState(); schedule();
  }

  // a truncated standard normal for every mode shown (the model's distribution, paper section 3.2)
  function randomCoefficient() {
    for (;;) {
      var u = 1 - Math.random(), v = Math.random();
      var z = Math.sqrt(-2 * Math.log(u)) * Math.cos(2 * Math.PI * v);
      if (Math.abs(z) <= LIMIT) return Math.round(z * 10) / 10;
    }
  }

  function setView(name) {
    Plotly.relayout(plot, {"scene.camera": CAMERAS[name]});
  }

  window.addEventListener("error", function (e) { status.errors.push(String(e.message)); });
  buildSliders();
  var select = document.getElementById("hs-colour");
  COLOURINGS.forEach(function (c) {
    var o = document.createElement("option");
    o.value = c;
    o.textContent = {shape: "plain", displacement: "displacement from the mean", sd: "the model's SD",
                     error: "geometric error map"}[c];
    select.appendChild(o);
  });
  select.addEventListener("change", function () { colour = select.value; writeFragment(); schedule(); });
  document.getElementById("hs-random").addEventListener("click", function () {
    for (var k = 0; k < K; k++) b[k] = randomCoefficient();
    showState(); writeFragment(); schedule();
  });
  document.getElementById("hs-reset").addEventListener("click", function () {
    b = new Array(K).fill(0); showState(); writeFragment(); schedule();
  });
  ["front", "top", "iso"].forEach(function (name) {
    document.getElementById("hs-view-" + name).addEventListener("click", function () { setView(name); });
  });
  window.addEventListener("hashchange", function () {
    if (window.location.hash !== fragmentOf(b, colour)) fromFragment();
  });
  status.shapeOf = shapeOf;  // for scripts that want the vertices drawn
  fromFragment();
})();
