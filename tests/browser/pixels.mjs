// What the Tank Viz view shows, read from a screenshot's pixels: each colour of the scene
// (bridge/scene.py) as connected blobs, and from them the ego box, lane lines, detections,
// tracks and the lead vehicle box.
//
// Colours as Foxglove's 3D panel draws them on the layout's #303030 background: lines are unlit
// (their exact colour, anti-aliased), spheres, boxes and cylinders are lit (about 0.73 of their
// colour facing the camera), see-through primitives are blended with what is behind them.

/** Pixel classes: name -> predicate on r, g, b (0-255). */
export const CLASSES = {
  // ego (0.72, 0.42, 0.16): lit about (192, 114, 52); not the MIO ring (no blue) or yellow
  ego: (r, g, b) => r >= 120 && r - g >= 45 && g - b >= 35 && b >= 22 && b <= 95 && g <= 150,
  // camera lanes (0, 0.9, 0.1) unlit, bright; neighbour lines and the see-through lead box dimmer
  green: (r, g, b) => g >= 90 && g - r >= 60 && g - b >= 50,
  brightGreen: (r, g, b) => g >= 185 && r <= 90 && b <= 110,
  // extrapolated lanes (1, 0, 1)
  magenta: (r, g, b) => r >= 140 && b >= 140 && g <= 90 && Math.abs(r - b) <= 70,
  // radar detections (0.1, 0.35, 1)
  blue: (r, g, b) => b >= 130 && b - r >= 90 && b - g >= 70,
  // tracks (1, 0.1, 0.1)
  red: (r, g, b) => r >= 130 && r - g >= 90 && r - b >= 90,
  // camera detections (1, 1, 1); text labels are white too (told apart by their black boxes)
  white: (r, g, b) => r >= 150 && g >= 150 && b >= 150 && Math.max(r, g, b) - Math.min(r, g, b) <= 24,
  // pedestrians (1, 0.85, 0)
  yellow: (r, g, b) => r >= 150 && g >= 120 && b <= 60 && r - g <= 70,
};

/** Connected blobs (4-neighbour) of one class inside a region of an RGBA image. */
export function blobs(image, predicate, region) {
  const { width, data } = image;
  const { x: rx, y: ry, width: rw, height: rh } = region;
  const mask = new Uint8Array(rw * rh);
  for (let y = 0; y < rh; y++) {
    for (let x = 0; x < rw; x++) {
      const i = ((ry + y) * width + rx + x) * 4;
      mask[y * rw + x] = predicate(data[i], data[i + 1], data[i + 2]) ? 1 : 0;
    }
  }
  const seen = new Uint8Array(rw * rh);
  const stack = new Int32Array(rw * rh);
  const out = [];
  for (let start = 0; start < mask.length; start++) {
    if (!mask[start] || seen[start]) {
      continue;
    }
    let top = 0;
    stack[top++] = start;
    seen[start] = 1;
    let area = 0;
    let x0 = rw;
    let y0 = rh;
    let x1 = -1;
    let y1 = -1;
    let sx = 0;
    let sy = 0;
    while (top > 0) {
      const p = stack[--top];
      const px = p % rw;
      const py = (p - px) / rw;
      area++;
      sx += px;
      sy += py;
      if (px < x0) x0 = px;
      if (px > x1) x1 = px;
      if (py < y0) y0 = py;
      if (py > y1) y1 = py;
      const next = [px > 0 ? p - 1 : -1, px < rw - 1 ? p + 1 : -1, py > 0 ? p - rw : -1,
        py < rh - 1 ? p + rw : -1];
      for (const q of next) {
        if (q >= 0 && mask[q] && !seen[q]) {
          seen[q] = 1;
          stack[top++] = q;
        }
      }
    }
    const w = x1 - x0 + 1;
    const h = y1 - y0 + 1;
    out.push({
      area,
      x0: x0 + rx,
      y0: y0 + ry,
      x1: x1 + rx,
      y1: y1 + ry,
      w,
      h,
      cx: Math.round(sx / area) + rx,
      cy: Math.round(sy / area) + ry,
      fill: +(area / (w * h)).toFixed(3),
    });
  }
  out.sort((a, b) => b.area - a.area);
  return out;
}

/** Share of the pixels on a blob's surrounding ring (2 px out) that are near black. */
function blackAround(image, blob) {
  const { width, height, data } = image;
  let black = 0;
  let total = 0;
  for (let y = blob.y0 - 2; y <= blob.y1 + 2; y++) {
    for (let x = blob.x0 - 2; x <= blob.x1 + 2; x++) {
      const inside = x >= blob.x0 && x <= blob.x1 && y >= blob.y0 && y <= blob.y1;
      if (inside || x < 0 || y < 0 || x >= width || y >= height) {
        continue;
      }
      const i = (y * width + x) * 4;
      total++;
      if (data[i] < 20 && data[i + 1] < 20 && data[i + 2] < 20) {
        black++;
      }
    }
  }
  return total ? black / total : 0;
}

const isLine = (b, minSpan) => b.h >= minSpan && b.fill < 0.35;
const isRound = (b, min) => b.w >= min && b.h >= min && b.w <= 4 * b.h && b.h <= 4 * b.w && b.fill >= 0.45;

/**
 * The Tank Viz reading of a screenshot region (the 3D panel's canvas): returns what was found
 * and a verdict per element of the view.
 */
export function readTankViz(image, region) {
  const found = {};
  for (const [name, predicate] of Object.entries(CLASSES)) {
    found[name] = blobs(image, predicate, region).filter((b) => b.area >= 4);
  }
  const W = region.width;
  const H = region.height;
  const relX = (b) => (b.cx - region.x) / W;
  const relY = (b) => (b.cy - region.y) / H;

  // The ego box: the largest orange-brown blob, in the lower middle of the view.
  const ego = found.ego.find((b) => b.area >= 150 && b.fill >= 0.4) ?? null;
  const egoAt = ego
    ? { x: +relX(ego).toFixed(3), y: +relY(ego).toFixed(3) }
    : null;
  // Near the ego box the sensor frames' axes are drawn (red, green, blue): not scene objects.
  const nearEgo = (b) =>
    ego !== null &&
    b.cx >= ego.x0 - ego.w && b.cx <= ego.x1 + ego.w && b.cy >= ego.y0 - ego.h && b.cy <= ego.y1 + ego.h;
  const away = (list) => list.filter((b) => !nearEgo(b));

  const minSpan = Math.round(H * 0.2);
  const greenLines = away(found.green).filter((b) => isLine(b, minSpan));
  const brightLines = away(found.brightGreen).filter((b) => isLine(b, minSpan));
  const magentaLines = away(found.magenta).filter((b) => isLine(b, minSpan));
  // The lead box: a compact, filled green blob ahead of the ego (see-through: it may be cut by
  // the red track sphere inside it and by labels; the largest piece counts).
  const leadBoxes = away(found.green).filter(
    (b) => isRound(b, 8) && b.area >= 60 && (!ego || b.cy < ego.y0),
  );
  const spheres = (list, min = 3) => away(list).filter((b) => isRound(b, min));
  const whiteSpheres = spheres(found.white).filter((b) => blackAround(image, b) < 0.25);
  const summary = (list) => list.slice(0, 12).map(({ area, cx, cy, w, h, fill }) => ({ area, cx, cy, w, h, fill }));

  return {
    region,
    ego: ego ? { ...summary([ego])[0], rel: egoAt } : null,
    egoBottomCentre: egoAt !== null && egoAt.x > 0.35 && egoAt.x < 0.65 && egoAt.y > 0.6,
    lanes: {
      green: summary(greenLines),
      brightGreen: summary(brightLines),
      magenta: summary(magentaLines),
    },
    radar: summary(spheres(found.blue)),
    camera: summary(whiteSpheres),
    tracks: summary(spheres(found.red)),
    // every red and blue blob away from the ego (not only the first 12), to count places
    redBlobs: away(found.red).map(({ area, cx, cy, x0, y0, x1, y1 }) => ({ area, cx, cy, x0, y0, x1, y1 })),
    blueBlobs: away(found.blue).map(({ area, cx, cy, x0, y0, x1, y1 }) => ({ area, cx, cy, x0, y0, x1, y1 })),
    lead: summary(leadBoxes),
    pedestrians: summary(away(found.yellow).filter((b) => b.area >= 20)),
    counts: Object.fromEntries(
      Object.entries(found).map(([name, list]) => [name, list.reduce((n, b) => n + b.area, 0)]),
    ),
  };
}

/** Which elements of the view are on screen (the test's checks, also used to wait for them). */
export function verdict(reading) {
  return {
    ego: reading.egoBottomCentre,
    greenLanes: reading.lanes.brightGreen.length >= 2,
    magentaLanes: reading.lanes.magenta.length >= 2,
    radar: reading.radar.length >= 1,
    camera: reading.camera.length >= 1,
    tracks: reading.tracks.length >= 1,
    lead: reading.lead.length >= 1,
  };
}
