//! Bad and odd mesh inputs, generated (small, no copies of anyone's files): the cases of
//! issue 14 that crashed, spun or were refused while peers read them. The regression tests
//! run each through the binary; the fuzz tests use them as seeds.

/// What reading a corpus file must give.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Expect {
    /// Exit 2 with one line containing this text (also under `--strict`).
    Refused(&'static str),
    /// Read, with a warning containing the first text; refused under `--strict` with an
    /// error containing the second.
    Lenient(&'static str, &'static str),
    /// Read without a warning.
    Clean,
}

/// One corpus file.
pub struct Case {
    /// File name (the extension picks the reader when the content does not).
    pub name: &'static str,
    /// The bytes.
    pub bytes: Vec<u8>,
    /// What reading must give.
    pub expect: Expect,
}

fn ply_header(format: &str, elements: &str) -> String {
    format!("ply\nformat {format} 1.0\n{elements}end_header\n")
}

const XYZ: &str = "property float x\nproperty float y\nproperty float z\n";

/// A unit square of two triangles as OBJ vertex lines.
const SQUARE: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n";

/// Every corpus case.
pub fn cases() -> Vec<Case> {
    let mut v = Vec::new();
    let mut add = |name, bytes: Vec<u8>, expect| {
        v.push(Case {
            name,
            bytes,
            expect,
        })
    };
    // PLY: a vertex count of 10^12 (reserved 12 TB and aborted).
    add(
        "vertex_1e12.ply",
        format!(
            "{}0 0 0\n",
            ply_header("ascii", &format!("element vertex 1000000000000\n{XYZ}"))
        )
        .into_bytes(),
        Expect::Refused("element `vertex` declares 1000000000000 records"),
    );
    // PLY: binary, a vertex count of 2^62 (capacity overflow panic in `simplify`).
    add(
        "vertex_2e62.ply",
        ply_header(
            "binary_little_endian",
            &format!("element vertex 4611686018427387904\n{XYZ}"),
        )
        .into_bytes(),
        Expect::Refused("element `vertex` declares 4611686018427387904 records"),
    );
    // PLY: an element without properties and 10^18 records (spun forever); the mesh
    // itself is fine.
    add(
        "empty_element_1e18.ply",
        format!(
            "{}0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
            ply_header(
                "ascii",
                &format!(
                    "element vertex 3\n{XYZ}element junk 1000000000000000000\n\
                     element face 1\nproperty list uchar int vertex_indices\n"
                )
            )
        )
        .into_bytes(),
        Expect::Clean,
    );
    // PLY: a face list claiming 10^18 faces in a binary file.
    add(
        "faces_1e18.ply",
        {
            let mut b = ply_header(
                "binary_little_endian",
                &format!(
                    "element vertex 3\n{XYZ}element face 1000000000000000000\n\
                     property list uchar int vertex_indices\n"
                ),
            )
            .into_bytes();
            for x in [0f32, 0., 0., 1., 0., 0., 0., 1., 0.] {
                b.extend_from_slice(&x.to_le_bytes());
            }
            b.push(3);
            for i in 0i32..3 {
                b.extend_from_slice(&i.to_le_bytes());
            }
            b
        },
        Expect::Refused("element `face` declares 1000000000000000000 records"),
    );
    // PLY: a NaN colour (dropped) and a face with 2 vertices (skipped).
    add(
        "nan_colour_short_face.ply",
        format!(
            "{}0 0 0 1 0 0\n1 0 0 nan 0 0\n0 1 0 0 0 1\n2 0 1\n3 0 1 2\n",
            ply_header(
                "ascii",
                &format!(
                    "element vertex 3\n{XYZ}property float red\nproperty float green\n\
                     property float blue\nelement face 2\nproperty list uchar int vertex_indices\n"
                )
            )
        )
        .into_bytes(),
        Expect::Lenient(
            "is not finite: colours dropped",
            "colour [NaN, 0.0, 0.0, 1.0] is not finite",
        ),
    );
    // PLY: a NaN position stays an error.
    add(
        "nan_position.ply",
        format!(
            "{}0 0 0\nnan 0 0\n0 1 0\n3 0 1 2\n",
            ply_header(
                "ascii",
                &format!("element vertex 3\n{XYZ}element face 1\nproperty list uchar int vertex_indices\n")
            )
        )
        .into_bytes(),
        Expect::Refused("non-finite coordinate"),
    );
    // OBJ (like trimesh's cubevt.obj): a texture-coordinate index out of range.
    add(
        "texture_index_out_of_range.obj",
        format!("{SQUARE}vt 0 0\nvt 1 0\nvt 1 1\nf 1/1 2/2 3/3\nf 1/1 3/3 4/7\n").into_bytes(),
        Expect::Lenient(
            "texture_index_out_of_range.obj:9: face texture coordinate index 7 is out of range: the file has 3 texture coordinates: texture coordinates dropped",
            "texture_index_out_of_range.obj:9: face texture coordinate index 7 is out of range",
        ),
    );
    // OBJ (like face_in_group_name_mid_file.obj): a normal index out of range, mid-file
    // after a group line.
    add(
        "normal_index_out_of_range.obj",
        format!("{SQUARE}vn 0 0 1\ng first\nf 1//1 2//1 3//1\ng second\nf 1//2 3//2 4//2\n")
            .into_bytes(),
        Expect::Lenient(
            "normal_index_out_of_range.obj:9: face normal index 2 is out of range: the file has 1 normals: normals dropped",
            "normal_index_out_of_range.obj:9: face normal index 2 is out of range",
        ),
    );
    // OBJ (like nancolor.obj): a `nan` vertex colour.
    add(
        "nan_colour.obj",
        b"v 0 0 0 0.5 0.5 0.5\nv 1 0 0 nan nan nan\nv 1 1 0 0.1 0.2 0.3\nv 0 1 0 1 1 1\nf 1 2 3\nf 1 3 4\n"
            .to_vec(),
        Expect::Lenient(
            "nan_colour.obj:2: colour value `nan` is not a finite number: vertex colours dropped",
            "nan_colour.obj:2: colour value `nan` is not a finite number",
        ),
    );
    // OBJ (like notenoughindices.obj): faces with two indices among good ones.
    add(
        "two_index_faces.obj",
        format!("{SQUARE}f 1 2\nf 1 2 3\nf 3 4\nf 1 3 4\n").into_bytes(),
        Expect::Lenient(
            "two_index_faces.obj:5: a face needs at least 3 vertices, this one has 2: skipped (and 1 more)",
            "two_index_faces.obj:5: a face needs at least 3 vertices, this one has 2",
        ),
    );
    // OBJ (like wallhole.obj): a face continued over lines with `\`.
    add(
        "line_continuation.obj",
        format!("{SQUARE}f 1 2 \\\n3 \\\r\n4\n").into_bytes(),
        Expect::Clean,
    );
    // OBJ: a vertex index out of range and a NaN position stay errors.
    add(
        "vertex_index_out_of_range.obj",
        format!("{SQUARE}f 1 2 5\n").into_bytes(),
        Expect::Refused("face vertex index 5 is out of range"),
    );
    add(
        "nan_position.obj",
        b"v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n".to_vec(),
        Expect::Refused("`nan` is not a finite number"),
    );
    // glb: an accessor count far past its buffer view.
    let quad = |count: &str, extra: &str| {
        glb(
            &format!(
                r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],{extra}
                "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"indices":1}}]}}],
                "accessors":[{{"bufferView":0,"componentType":5126,"count":{count},"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
                {{"bufferView":1,"componentType":5125,"count":6,"type":"SCALAR"}}],
                "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":48}},{{"buffer":0,"byteOffset":48,"byteLength":24}}],
                "buffers":[{{"byteLength":72}}]}}"#
            ),
            &square_bin(),
        )
    };
    add(
        "count_2e32.glb",
        quad("4294967295", r#""nodes":[{"mesh":0}],"#),
        Expect::Refused("do not fit in its buffer view"),
    );
    add(
        "quad.glb",
        quad("4", r#""nodes":[{"mesh":0}],"#),
        Expect::Clean,
    );
    // glb: POSITION names an accessor that does not exist (panicked inside gltf-json's
    // validation; found by the mutation fuzzer).
    let mut missing = quad("4", r#""nodes":[{"mesh":0}],"#);
    let at = missing
        .windows(12)
        .position(|w| w == b"\"POSITION\":0")
        .unwrap();
    missing[at + 11] = b'7';
    add(
        "position_accessor_missing.glb",
        missing,
        Expect::Refused("= 7 but there are 2 accessors"),
    );
    // glb: a node that is its own child (a cycle).
    add(
        "node_cycle.glb",
        quad("4", r#""nodes":[{"mesh":0,"children":[0]}],"#),
        Expect::Refused("node 0"),
    );
    // glb: 4,000 nodes instancing one mesh: more vertex data than the file could justify.
    let many: Vec<String> = (0..4000).map(|_| r#"{"mesh":0}"#.to_string()).collect();
    let roots: Vec<String> = (0..4000).map(|i| i.to_string()).collect();
    add(
        "instances.glb",
        glb(
            &format!(
                r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[{}]}}],"nodes":[{}],
                "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],
                "accessors":[{{"bufferView":0,"componentType":5126,"count":6000,"type":"VEC3","min":[0,0,0],"max":[0,0,0]}}],
                "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":72000}}],
                "buffers":[{{"byteLength":72000}}]}}"#,
                roots.join(","),
                many.join(",")
            ),
            &vec![0u8; 72000],
        ),
        Expect::Refused("more than 8 times the file's"),
    );
    v
}

/// The unit square's 4 float positions and 6 u32 indices.
fn square_bin() -> Vec<u8> {
    let mut b = Vec::new();
    for x in [0f32, 0., 0., 1., 0., 0., 1., 0., 1., 0., 0., 1.] {
        b.extend_from_slice(&x.to_le_bytes());
    }
    for i in [0u32, 1, 2, 0, 2, 3] {
        b.extend_from_slice(&i.to_le_bytes());
    }
    b
}

/// A glb container of `json` and `bin` (the library's framing: the corpus is about what is
/// inside the chunks).
pub fn glb(json: &str, bin: &[u8]) -> Vec<u8> {
    terratile::mesh::io::glb_container(json.as_bytes(), bin)
}
