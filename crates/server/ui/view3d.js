// 3D segments in a three.js scene: orbit with the mouse, wheel to zoom, click a segment to
// pick it. Frames: the data's own (z up for a session map, the rig frame for a Match); the
// view turns them so that `up` is up on screen.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

export function webglAvailable() {
  try {
    const canvas = document.createElement('canvas');
    return Boolean(canvas.getContext('webgl2') || canvas.getContext('webgl'));
  } catch {
    return false;
  }
}

export class View3d {
  // `container`: an element with a size; `up`: the data's up axis as [x, y, z].
  constructor(container, { up = [0, 0, 1], onPick = () => {} } = {}) {
    this.container = container;
    this.onPick = onPick;
    this.renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
    this.renderer.setPixelRatio(window.devicePixelRatio);
    this.renderer.setClearColor(0xfafafa);
    container.append(this.renderer.domElement);
    this.scene = new THREE.Scene();
    this.camera = new THREE.PerspectiveCamera(50, 1, 0.01, 1000);
    this.camera.up.set(...up);
    this.controls = new OrbitControls(this.camera, this.renderer.domElement);
    this.controls.addEventListener('change', () => this.draw());
    this.group = new THREE.Group();
    this.scene.add(this.group);
    this.picked = null;
    this.raycaster = new THREE.Raycaster();
    this.renderer.domElement.addEventListener('click', (event) => this.pick(event));
    new ResizeObserver(() => this.resize()).observe(container);
    this.resize();
  }

  resize() {
    const { clientWidth: w, clientHeight: h } = this.container;
    if (w === 0 || h === 0) return;
    this.renderer.setSize(w, h);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
    this.draw();
  }

  draw() {
    this.renderer.render(this.scene, this.camera);
  }

  // segments: [{ start: [x, y, z], end: [x, y, z], colour: '#rrggbb' or css, data }];
  // markers: [{ at: [x, y, z], towards: [x, y, z] or null, colour }] (rig poses).
  // The first call frames the camera on what is drawn; later ones keep the user's view.
  show(segments, markers = [], { grid = true } = {}) {
    for (const child of [...this.group.children]) {
      this.group.remove(child);
      child.geometry?.dispose();
      child.material?.dispose();
    }
    const positions = new Float32Array(segments.length * 6);
    const colours = new Float32Array(segments.length * 6);
    const c = new THREE.Color();
    segments.forEach((s, i) => {
      positions.set([...s.start, ...s.end], 6 * i);
      c.setStyle(s.colour);
      colours.set([c.r, c.g, c.b, c.r, c.g, c.b], 6 * i);
    });
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute('position', new THREE.BufferAttribute(positions, 3));
    geometry.setAttribute('color', new THREE.BufferAttribute(colours, 3));
    this.lines = new THREE.LineSegments(geometry, new THREE.LineBasicMaterial({ vertexColors: true }));
    this.lines.userData.segments = segments;
    this.group.add(this.lines);
    geometry.computeBoundingSphere();
    const sphere = geometry.boundingSphere;
    const radius = segments.length ? Math.max(sphere.radius, 0.5) : 3;
    const centre = segments.length ? sphere.center : new THREE.Vector3();
    for (const m of markers) {
      const dot = new THREE.Mesh(
        new THREE.SphereGeometry(Math.max(radius / 80, 0.01), 12, 8),
        new THREE.MeshBasicMaterial({ color: m.colour }),
      );
      dot.position.set(...m.at);
      this.group.add(dot);
      if (m.towards) {
        const to = new THREE.Vector3(...m.towards);
        const from = new THREE.Vector3(...m.at);
        const g = new THREE.BufferGeometry().setFromPoints([from, to]);
        this.group.add(new THREE.Line(g, new THREE.LineBasicMaterial({ color: m.colour })));
      }
    }
    if (grid) {
      // One-metre grid in the plane across `up`, under the data.
      const size = Math.max(2, 2 * Math.ceil(radius + 1));
      const helper = new THREE.GridHelper(size, size, 0x999999, 0xdddddd);
      const up = this.camera.up.clone().normalize();
      helper.quaternion.setFromUnitVectors(new THREE.Vector3(0, 1, 0), up);
      const low = segments.length
        ? Math.min(...segments.flatMap((s) => [new THREE.Vector3(...s.start).dot(up), new THREE.Vector3(...s.end).dot(up)]))
        : 0;
      helper.position.copy(centre).addScaledVector(up, low - centre.dot(up));
      this.group.add(helper);
      this.group.add(new THREE.AxesHelper(1));
    }
    this.raycaster.params.Line.threshold = radius / 150;
    if (!this.framed) {
      this.framed = true;
      this.controls.target.copy(centre);
      const away = new THREE.Vector3(1, -1.5, 1).normalize();
      if (this.camera.up.y > 0.5) away.set(0.6, 0.8, -1.6).normalize();
      this.camera.position.copy(centre).addScaledVector(away, 2.6 * radius);
      this.camera.near = radius / 100;
      this.camera.far = radius * 100;
      this.camera.updateProjectionMatrix();
      this.controls.update();
    }
    this.draw();
  }

  pick(event) {
    if (!this.lines) return;
    const box = this.renderer.domElement.getBoundingClientRect();
    const pointer = new THREE.Vector2(
      ((event.clientX - box.left) / box.width) * 2 - 1,
      -((event.clientY - box.top) / box.height) * 2 + 1,
    );
    this.raycaster.setFromCamera(pointer, this.camera);
    const hit = this.raycaster.intersectObject(this.lines)[0];
    if (!hit) return;
    const index = Math.floor(hit.index / 2);
    this.highlight(index);
    this.onPick(this.lines.userData.segments[index], index);
  }

  highlight(index) {
    this.picked?.removeFromParent();
    const s = this.lines.userData.segments[index];
    const g = new THREE.BufferGeometry().setFromPoints([new THREE.Vector3(...s.start), new THREE.Vector3(...s.end)]);
    this.picked = new THREE.Line(g, new THREE.LineBasicMaterial({ color: 0xff2d55 }));
    this.group.add(this.picked);
    this.draw();
  }
}
