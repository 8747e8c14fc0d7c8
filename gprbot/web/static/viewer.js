// gprbot: the 3D viewer of a run (three.js passed in): sparse and dense clouds, pipes, surveyed area, depth scale.
// Site frame: x forward, y left, z up (the camera's up is +z). Orbit: drag to turn, wheel to zoom, shift-drag to pan.
"use strict";
(function () {
  function cloudPoints(THREE, cloud, size, fallback) {
    const xyz = GprDraw.b64float32(cloud.xyz), geometry = new THREE.BufferGeometry();
    geometry.setAttribute("position", new THREE.BufferAttribute(new Float32Array(xyz), 3));
    let material;
    if (cloud.rgb) {
      const rgb = GprDraw.b64bytes(cloud.rgb), colours = new Float32Array(rgb.length);
      for (let i = 0; i < rgb.length; i++) colours[i] = rgb[i] / 255;
      geometry.setAttribute("color", new THREE.BufferAttribute(colours, 3));
      material = new THREE.PointsMaterial({ size, vertexColors: true, sizeAttenuation: false });
    } else {
      material = new THREE.PointsMaterial({ size, color: fallback, sizeAttenuation: false });
    }
    return new THREE.Points(geometry, material);
  }

  function label(THREE, text, colour, height) {
    const c = document.createElement("canvas"); c.width = 128; c.height = 32;
    const ctx = c.getContext("2d"); ctx.fillStyle = colour; ctx.font = "20px system-ui, sans-serif"; ctx.fillText(text, 4, 22);
    const sprite = new THREE.Sprite(new THREE.SpriteMaterial({ map: new THREE.CanvasTexture(c), depthTest: false }));
    sprite.scale.set(4 * height, height, 1);
    return sprite;
  }

  function create(canvas, THREE, doc) {
    const renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
    renderer.setPixelRatio(1);
    renderer.setClearColor(0x0b0d10, 1);
    const scene = new THREE.Scene(), groups = { sparse: new THREE.Group(), dense: new THREE.Group(), pipes: new THREE.Group() };
    Object.values(groups).forEach((g) => scene.add(g));
    let count = 0;
    if (doc.sparse && doc.sparse.xyz) { groups.sparse.add(cloudPoints(THREE, doc.sparse, 4, 0xdddddd)); count += doc.sparse.count; }
    if (doc.dense && doc.dense.xyz) { groups.dense.add(cloudPoints(THREE, doc.dense, 3, 0x4aa3ff)); count += doc.dense.count; }
    const pipes = (doc.pipes && doc.pipes.pipes) || [];
    for (const pipe of pipes) {
      const pts = pipe.axis_m.map((p) => new THREE.Vector3(p[0], p[1], p[2]));
      if (pts.length < 2) continue;
      const curve = new THREE.CatmullRomCurve3(pts), tube = new THREE.TubeGeometry(curve, 32, pipe.diameter_m / 2, 12, false);
      const mesh = new THREE.Mesh(tube, new THREE.MeshBasicMaterial({ color: pipe.colour || "#ffaa00", transparent: true, opacity: 0.35, depthWrite: false }));
      groups.pipes.add(mesh);
    }
    // the surveyed area at the surface and a depth scale at its corner
    const a = doc.area || boundsOf(doc);
    const zMin = Math.min(-0.3, ...pipes.map((p) => Math.min(...p.axis_m.map((q) => q[2])) - 0.05));
    const outline = new THREE.BufferGeometry().setFromPoints([[a[0], a[2]], [a[1], a[2]], [a[1], a[3]], [a[0], a[3]]]
      .map(([x, y]) => new THREE.Vector3(x, y, 0)));
    scene.add(new THREE.LineLoop(outline, new THREE.LineBasicMaterial({ color: 0x8899aa })));
    // the volume under the surveyed area, dimmer, so that "below the surface" reads at a glance
    const box = [];
    for (const [x, y] of [[a[0], a[2]], [a[1], a[2]], [a[1], a[3]], [a[0], a[3]]]) box.push(new THREE.Vector3(x, y, 0), new THREE.Vector3(x, y, zMin));
    [[a[0], a[2], a[1], a[2]], [a[1], a[2], a[1], a[3]], [a[1], a[3], a[0], a[3]], [a[0], a[3], a[0], a[2]]]
      .forEach(([x0, y0, x1, y1]) => box.push(new THREE.Vector3(x0, y0, zMin), new THREE.Vector3(x1, y1, zMin)));
    scene.add(new THREE.LineSegments(new THREE.BufferGeometry().setFromPoints(box), new THREE.LineBasicMaterial({ color: 0x3a4550 })));
    const span = Math.max(a[1] - a[0], a[3] - a[2], -zMin), textH = 0.035 * span;
    const ruler = [], step = 0.05, x = a[0] - 0.05, y = a[2] - 0.05;
    ruler.push(new THREE.Vector3(x, y, 0), new THREE.Vector3(x, y, zMin));
    for (let z = 0; z >= zMin - 1e-9; z -= step) {
      ruler.push(new THREE.Vector3(x, y, z), new THREE.Vector3(x + 0.03, y, z));
      if (Math.round(-z / step) % 2 === 0) { const s = label(THREE, `${(-z * 100).toFixed(0)} cm`, "#cfd6dd", textH); s.position.set(x - 2.2 * textH, y, z); scene.add(s); }
    }
    scene.add(new THREE.LineSegments(new THREE.BufferGeometry().setFromPoints(ruler), new THREE.LineBasicMaterial({ color: 0xcfd6dd })));
    const centre = new THREE.Vector3((a[0] + a[1]) / 2, (a[2] + a[3]) / 2, zMin / 2);
    const radius = span * 2.0;
    const camera = new THREE.PerspectiveCamera(40, canvas.width / canvas.height, 0.01, 100);
    camera.up.set(0, 0, 1);
    const view = { az: -Math.PI / 2 - 0.6, el: 0.55, r: radius, target: centre };
    function place() {
      const { az, el, r, target } = view;
      camera.position.set(target.x + r * Math.cos(el) * Math.cos(az), target.y + r * Math.cos(el) * Math.sin(az), target.z + r * Math.sin(el));
      camera.lookAt(target);
    }
    let pending = false;
    function render() { if (pending) return; pending = true; requestAnimationFrame(() => { pending = false; place(); renderer.render(scene, camera); }); }
    let drag = null;
    canvas.addEventListener("pointerdown", (e) => { drag = { x: e.clientX, y: e.clientY, pan: e.shiftKey || e.button === 2 }; canvas.setPointerCapture(e.pointerId); });
    canvas.addEventListener("pointermove", (e) => {
      if (!drag) return;
      const dx = e.clientX - drag.x, dy = e.clientY - drag.y; drag.x = e.clientX; drag.y = e.clientY;
      if (drag.pan) {
        const k = view.r / canvas.height, right = new THREE.Vector3(-Math.sin(view.az), Math.cos(view.az), 0);
        view.target.addScaledVector(right, dx * k); view.target.z += dy * k;
      } else { view.az -= dx * 0.01; view.el = Math.max(-1.4, Math.min(1.5, view.el + dy * 0.01)); }
      render();
    });
    canvas.addEventListener("pointerup", () => { drag = null; });
    canvas.addEventListener("contextmenu", (e) => e.preventDefault());
    canvas.addEventListener("wheel", (e) => { e.preventDefault(); view.r *= Math.exp(e.deltaY * 0.001); render(); }, { passive: false });
    place(); renderer.render(scene, camera);
    return {
      canvas, run: doc.run, points: count, pipes: pipes.length, render,
      show(name, visible) { groups[name].visible = visible; render(); },
      renderNow() { place(); renderer.render(scene, camera); },
    };
  }

  function boundsOf(doc) {
    const xyz = doc.dense && doc.dense.xyz ? GprDraw.b64float32(doc.dense.xyz) : new Float32Array([0, 0, 0, 1, 1, 0]);
    let [x0, x1, y0, y1] = [Infinity, -Infinity, Infinity, -Infinity];
    for (let i = 0; i < xyz.length; i += 3) { x0 = Math.min(x0, xyz[i]); x1 = Math.max(x1, xyz[i]); y0 = Math.min(y0, xyz[i + 1]); y1 = Math.max(y1, xyz[i + 1]); }
    return [x0, x1, y0, y1];
  }

  // Lit pixels of the viewer's canvas (what the browser tests count to know points were drawn).
  function litPixels(canvas) {
    const probe = document.createElement("canvas"); probe.width = canvas.width; probe.height = canvas.height;
    const ctx = probe.getContext("2d"); ctx.drawImage(canvas, 0, 0);
    const px = ctx.getImageData(0, 0, probe.width, probe.height).data;
    let lit = 0;
    for (let i = 0; i < px.length; i += 4) if (Math.abs(px[i] - 11) + Math.abs(px[i + 1] - 13) + Math.abs(px[i + 2] - 16) > 40) lit++;
    return lit;
  }

  window.GprViewer = { create, litPixels };
})();
