// Decodes every tile of a Cesium terrain tileset with HERE's independent decoder
// (npm @here/quantized-mesh-decoder) and prints one JSON document: layer.json's ranges and,
// per tile, the decoded header, vertices (quantized u, v, height), triangles, edge lists
// and oct-decoded normals. Usage: node decode_terrain.mjs NODE_MODULES_DIR TERRAIN_DIR
import { createRequire } from 'node:module'
import fs from 'node:fs'
import path from 'node:path'
import zlib from 'node:zlib'

const [modules, dir] = process.argv.slice(2)
const require = createRequire(path.join(modules, 'x.js'))
const decoder = require('@here/quantized-mesh-decoder')
const decode = decoder.default || decoder.decode || decoder

const layer = JSON.parse(fs.readFileSync(path.join(dir, 'layer.json'), 'utf8'))
const octDecode = (x, y) => {
  // Cesium's AttributeCompression.octDecode (range 255).
  let u = (x / 255) * 2 - 1
  let v = (y / 255) * 2 - 1
  const z = 1 - (Math.abs(u) + Math.abs(v))
  if (z < 0) {
    const ou = u
    u = (1 - Math.abs(v)) * (ou >= 0 ? 1 : -1)
    v = (1 - Math.abs(ou)) * (v >= 0 ? 1 : -1)
  }
  const l = Math.hypot(u, v, z)
  return [u / l, v / l, z / l]
}
const tiles = []
layer.available.forEach((ranges, z) => {
  for (const r of ranges) {
    for (let x = r.startX; x <= r.endX; x++) {
      for (let y = r.startY; y <= r.endY; y++) {
        const file = path.join(dir, String(z), String(x), `${y}.terrain`)
        const raw = fs.readFileSync(file)
        const gzipped = raw[0] === 0x1f && raw[1] === 0x8b
        const bytes = gzipped ? zlib.gunzipSync(raw) : raw
        const ab = bytes.buffer.slice(bytes.byteOffset, bytes.byteOffset + bytes.byteLength)
        const t = decode(ab)
        const n = t.vertexData.length / 3
        const normals = []
        const enc = t.extensions.vertexNormals
        for (let k = 0; enc && k < n; k++) normals.push(octDecode(enc[2 * k], enc[2 * k + 1]))
        tiles.push({
          z, x, y, gzipped,
          header: t.header,
          u: Array.from(t.vertexData.subarray(0, n)),
          v: Array.from(t.vertexData.subarray(n, 2 * n)),
          h: Array.from(t.vertexData.subarray(2 * n, 3 * n)),
          triangles: Array.from(t.triangleIndices),
          west: Array.from(t.westIndices),
          south: Array.from(t.southIndices),
          east: Array.from(t.eastIndices),
          north: Array.from(t.northIndices),
          normals
        })
      }
    }
  }
})
process.stdout.write(JSON.stringify({ layer, tiles }))
