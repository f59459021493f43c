// spherecal report: the interactive 3-D view of the mapped points (written for spherecal,
// no library, no network). Data: the JSON in #view3d-data: points (x, y, z relative to the
// fitted centre, mm, flattened), residuals (mm), radius_mm, limit_mm (colour limit), frame.
(function () {
  "use strict";
  var canvas = document.getElementById("view3d-canvas");
  var source = document.getElementById("view3d-data");
  if (!canvas || !source || !canvas.getContext) { return; }
  var data = JSON.parse(source.textContent);
  var ctx = canvas.getContext("2d");
  var gainInput = document.getElementById("view3d-gain");
  var gainOut = document.getElementById("view3d-gain-out");
  var n = data.residuals.length;
  var r = data.radius_mm;
  var yaw = -0.6, pitch = 0.45, zoom = 1.0, gain = 1.0;

  // blue (negative) - white - red (positive), clipped at +/- limit_mm
  function colour(res) {
    var t = Math.max(-1, Math.min(1, res / data.limit_mm));
    var a = Math.abs(t);
    var strong = Math.round(255 * (1 - 0.85 * a)), soft = Math.round(255 * (1 - 0.6 * a));
    return t < 0 ? "rgb(" + strong + "," + soft + ",255)" : "rgb(255," + Math.round(255 * (1 - 0.75 * a)) + ","
      + strong + ")";
  }
  var colours = new Array(n);
  for (var i = 0; i < n; i++) { colours[i] = colour(data.residuals[i]); }

  // rotation: yaw about z, then pitch about the screen's x axis; screen y points up
  function project(x, y, z) {
    var cy = Math.cos(yaw), sy = Math.sin(yaw), cp = Math.cos(pitch), sp = Math.sin(pitch);
    var x1 = cy * x - sy * y, y1 = sy * x + cy * y;
    var depth = cp * y1 - sp * z, up = sp * y1 + cp * z;
    var scale = zoom * 0.42 * Math.min(canvas.width, canvas.height) / (1.2 * r);
    return [canvas.width / 2 + scale * x1, canvas.height / 2 - scale * up, depth];
  }

  function drawCircle(points, back) {
    ctx.beginPath();
    var open = false;
    for (var k = 0; k < points.length; k++) {
      var p = project(points[k][0], points[k][1], points[k][2]);
      var behind = p[2] > 0;
      if (behind !== back) { open = false; continue; }
      if (!open) { ctx.moveTo(p[0], p[1]); open = true; } else { ctx.lineTo(p[0], p[1]); }
    }
    ctx.stroke();
  }

  function wire(back) {
    ctx.strokeStyle = back ? "#e8eaed" : "#bdc1c6";
    ctx.lineWidth = 0.7;
    var steps = 72, k, a, b, ring;
    for (var lat = -60; lat <= 60; lat += 30) {
      ring = [];
      b = lat * Math.PI / 180;
      for (k = 0; k <= steps; k++) {
        a = 2 * Math.PI * k / steps;
        ring.push([r * Math.cos(b) * Math.cos(a), r * Math.cos(b) * Math.sin(a), r * Math.sin(b)]);
      }
      drawCircle(ring, back);
    }
    for (var lon = 0; lon < 180; lon += 30) {
      ring = [];
      a = lon * Math.PI / 180;
      for (k = 0; k <= steps; k++) {
        b = 2 * Math.PI * k / steps;
        ring.push([r * Math.cos(b) * Math.cos(a), r * Math.cos(b) * Math.sin(a), r * Math.sin(b)]);
      }
      drawCircle(ring, back);
    }
  }

  function axes() {
    var o = project(0, 0, 0), names = ["x", "y", "z"], cols = ["#c5221f", "#188038", "#1a73e8"];
    for (var k = 0; k < 3; k++) {
      var e = [0, 0, 0];
      e[k] = 0.35 * r;
      var p = project(e[0], e[1], e[2]);
      ctx.strokeStyle = cols[k];
      ctx.lineWidth = 1.5;
      ctx.beginPath(); ctx.moveTo(o[0], o[1]); ctx.lineTo(p[0], p[1]); ctx.stroke();
      ctx.fillStyle = cols[k];
      ctx.fillText(data.frame + " " + names[k], p[0] + 3, p[1] - 3);
    }
  }

  function draw() {
    ctx.fillStyle = "#ffffff";
    ctx.fillRect(0, 0, canvas.width, canvas.height);
    ctx.font = "11px sans-serif";
    wire(true);
    var order = new Array(n), screen = new Array(n);
    for (var i = 0; i < n; i++) {
      var x = data.points[3 * i], y = data.points[3 * i + 1], z = data.points[3 * i + 2];
      var len = Math.sqrt(x * x + y * y + z * z) || 1;
      var push = (gain - 1) * data.residuals[i] / len;  // exaggerate the residual along the radius
      screen[i] = project(x * (1 + push), y * (1 + push), z * (1 + push));
      order[i] = i;
    }
    order.sort(function (a, b) { return screen[b][2] - screen[a][2]; });  // far first
    for (var j = 0; j < n; j++) {
      var q = screen[order[j]];
      ctx.fillStyle = colours[order[j]];
      ctx.fillRect(q[0] - 1.5, q[1] - 1.5, 3, 3);
    }
    wire(false);
    axes();
    ctx.fillStyle = "#202124";
    ctx.fillText("residual colour: -" + data.limit_mm + " mm (blue) to +" + data.limit_mm + " mm (red); radius "
      + r + " mm; residuals x" + gain.toFixed(gain < 10 ? 1 : 0), 8, canvas.height - 8);
    canvas.setAttribute("data-drawn", String(n));  // for tests: the view was drawn, with this many points
  }

  var dragging = null;
  canvas.addEventListener("mousedown", function (ev) { dragging = [ev.clientX, ev.clientY]; });
  window.addEventListener("mouseup", function () { dragging = null; });
  window.addEventListener("mousemove", function (ev) {
    if (!dragging) { return; }
    yaw += (ev.clientX - dragging[0]) * 0.01;
    pitch = Math.max(-1.55, Math.min(1.55, pitch + (ev.clientY - dragging[1]) * 0.01));
    dragging = [ev.clientX, ev.clientY];
    draw();
  });
  canvas.addEventListener("wheel", function (ev) {
    ev.preventDefault();
    zoom = Math.max(0.3, Math.min(8, zoom * (ev.deltaY < 0 ? 1.1 : 1 / 1.1)));
    draw();
  }, { passive: false });
  canvas.addEventListener("keydown", function (ev) {
    if (ev.key === "+" || ev.key === "=") { zoom = Math.min(8, zoom * 1.1); }
    else if (ev.key === "-") { zoom = Math.max(0.3, zoom / 1.1); }
    else if (ev.key === "ArrowLeft") { yaw -= 0.1; }
    else if (ev.key === "ArrowRight") { yaw += 0.1; }
    else if (ev.key === "ArrowUp") { pitch = Math.max(-1.55, pitch - 0.1); }
    else if (ev.key === "ArrowDown") { pitch = Math.min(1.55, pitch + 0.1); }
    else { return; }
    ev.preventDefault();
    draw();
  });
  canvas.addEventListener("dblclick", function () { yaw = -0.6; pitch = 0.45; zoom = 1.0; draw(); });
  if (gainInput) {
    gainInput.addEventListener("input", function () {
      gain = Math.pow(10, parseFloat(gainInput.value) || 0);
      if (gainOut) { gainOut.textContent = "x" + (gain < 10 ? gain.toFixed(1) : gain.toFixed(0)); }
      draw();
    });
  }
  draw();
}());
