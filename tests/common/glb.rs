#![allow(dead_code)]
//! A minimal reader of binary glTF for tests: the container, the JSON and accessors of
//! float and unsigned-int data, written from the glTF 2.0 specification and independent of
//! the writer (src/io/gltf.rs).

use serde_json::Value;
use std::path::Path;

pub struct Glb {
    pub json: Value,
    pub bin: Vec<u8>,
}

fn u32_at(b: &[u8], i: usize) -> u32 {
    u32::from_le_bytes(b[i..i + 4].try_into().unwrap())
}

/// Parses `path`; panics with a message on anything malformed.
pub fn read(path: &Path) -> Glb {
    let b = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    assert_eq!(&b[..4], b"glTF", "magic");
    assert_eq!(u32_at(&b, 4), 2, "version");
    assert_eq!(u32_at(&b, 8) as usize, b.len(), "length");
    let jlen = u32_at(&b, 12) as usize;
    assert_eq!(&b[16..20], b"JSON");
    assert_eq!(jlen % 4, 0);
    let json: Value = serde_json::from_slice(&b[20..20 + jlen]).expect("JSON chunk");
    let at = 20 + jlen;
    let blen = u32_at(&b, at) as usize;
    assert_eq!(&b[at + 4..at + 8], b"BIN\0");
    assert_eq!(at + 8 + blen, b.len());
    Glb {
        json,
        bin: b[at + 8..].to_vec(),
    }
}

impl Glb {
    fn view(&self, v: usize) -> &[u8] {
        let view = &self.json["bufferViews"][v];
        assert_eq!(view["buffer"], 0);
        let off = view["byteOffset"].as_u64().unwrap_or(0) as usize;
        let len = view["byteLength"].as_u64().unwrap() as usize;
        &self.bin[off..off + len]
    }

    /// Accessor `a` as rows of f32 (component type 5126) or u32 (5125) values.
    pub fn accessor(&self, a: usize) -> Vec<Vec<f64>> {
        let acc = &self.json["accessors"][a];
        let k = match acc["type"].as_str().unwrap() {
            "SCALAR" => 1,
            "VEC2" => 2,
            "VEC3" => 3,
            "VEC4" => 4,
            t => panic!("accessor type {t}"),
        };
        let count = acc["count"].as_u64().unwrap() as usize;
        let data = &self.view(acc["bufferView"].as_u64().unwrap() as usize)
            [acc["byteOffset"].as_u64().unwrap_or(0) as usize..];
        let comp = acc["componentType"].as_u64().unwrap();
        assert!(comp == 5126 || comp == 5125, "component type {comp}");
        assert!(data.len() >= count * k * 4);
        (0..count)
            .map(|i| {
                (0..k)
                    .map(|j| {
                        let w = &data[(i * k + j) * 4..(i * k + j + 1) * 4];
                        if comp == 5126 {
                            f32::from_le_bytes(w.try_into().unwrap()) as f64
                        } else {
                            u32::from_le_bytes(w.try_into().unwrap()) as f64
                        }
                    })
                    .collect()
            })
            .collect()
    }

    fn primitive(&self) -> &Value {
        let meshes = self.json["meshes"].as_array().unwrap();
        assert_eq!(meshes.len(), 1);
        let p = meshes[0]["primitives"].as_array().unwrap();
        assert_eq!(p.len(), 1);
        &p[0]
    }

    /// A vertex attribute of the (single) primitive, if present.
    pub fn attribute(&self, name: &str) -> Option<Vec<Vec<f64>>> {
        let a = self.primitive()["attributes"][name].as_u64()?;
        Some(self.accessor(a as usize))
    }

    /// The triangles of the (single) primitive.
    pub fn triangles(&self) -> Vec<[usize; 3]> {
        let p = self.primitive();
        assert!(p["mode"].is_null() || p["mode"] == 4, "triangles");
        let idx = self.accessor(p["indices"].as_u64().unwrap() as usize);
        idx.chunks(3)
            .map(|t| [t[0][0] as usize, t[1][0] as usize, t[2][0] as usize])
            .collect()
    }

    /// The material of the primitive.
    pub fn material(&self) -> &Value {
        &self.json["materials"][self.primitive()["material"].as_u64().unwrap() as usize]
    }

    /// The image bytes behind texture `t`.
    pub fn texture_image(&self, t: usize) -> &[u8] {
        let img = self.json["textures"][t]["source"].as_u64().unwrap() as usize;
        let image = &self.json["images"][img];
        assert_eq!(image["mimeType"], "image/png");
        self.view(image["bufferView"].as_u64().unwrap() as usize)
    }
}
