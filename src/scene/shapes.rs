//! The shapes of the built-in still scenes, generated in code in the frame of
//! the McGuire Cornell-box OBJ files: the box spans x and z in [-1, 1] and y in
//! [0, 2], open at z = +1, with an emissive quad just under the ceiling. Colours
//! are the classic box's: red left wall, green right wall, white elsewhere.
//! [`super::builtin`] names them; the forest and the animations build on them.

use std::f32::consts::PI;

use glam::Vec3;

use super::{Material, Scene};
use crate::error::{Error, Result};

/// Triangle budget of `mesh:N` scenes.
pub const MESH_TRIANGLES: std::ops::RangeInclusive<u64> = 100..=100_000_000;

/// The still built-in scene called `name` (neither animated nor instanced);
/// `None` when no still built-in has that name.
pub(super) fn still(name: &str) -> Result<Option<Scene>> {
    let mut b = Builder::default();
    // Scenes with no box, framed from their bounds as a file would be.
    let unframed = [
        ("plane", 2..=10_000_000),
        ("pipes", 100..=10_000_000),
        ("overlap", 10..=10_000_000),
        ("far", *MESH_TRIANGLES.start()..=10_000_000),
    ];
    if let Some((prefix, range)) = unframed
        .into_iter()
        .find(|(p, _)| name.strip_prefix(p).is_some_and(|r| r.starts_with(':')))
    {
        let n = parse_count(name, prefix, range)? as usize;
        match prefix {
            "plane" => b.field(n),
            "pipes" => b.pipes(n),
            "overlap" => b.overlap(n),
            _ => {
                b.cornell_box();
                b.displaced_sphere(n as u64);
                for p in &mut b.positions {
                    *p += Vec3::new(1e5, 0.0, 1e5);
                }
            }
        }
        return b.into_scene(name).map(Some);
    }
    b.cornell_box();
    match name {
        "cornell-empty" => {}
        "cornell-original" => {
            let white = b.material(Material::diffuse("shortBox", WHITE));
            // Footprints of the classic blocks (the Cornell data, as in the OBJ files).
            b.block(
                [[0.53, 0.75], [0.70, 0.17], [0.13, 0.00], [-0.05, 0.57]],
                0.6,
                white,
            );
            b.block(
                [[-0.53, 0.09], [0.04, -0.09], [-0.14, -0.67], [-0.71, -0.49]],
                1.2,
                white,
            );
        }
        "cornell-sphere" => b.spheres(),
        "cornell-water" => {
            b.spheres();
            b.water();
        }
        _ if name.starts_with("mesh:") => {
            let n = parse_count(name, "mesh", MESH_TRIANGLES)?;
            b.displaced_sphere(n);
        }
        _ if name.starts_with("grass:") => {
            let n = parse_count(name, "grass", 100..=10_000_000)?;
            b.grass(n as usize);
        }
        _ if name.starts_with("city:") => {
            let n = parse_count(name, "city", 10..=1_000_000)?;
            b.city(n as usize, 0.0);
        }
        _ if name.starts_with("rooms:") => {
            let n = parse_count(name, "rooms", 200..=10_000_000)?;
            // The interior replaces the box (its walls would enclose one room).
            b = Builder::default();
            b.rooms(n as usize);
        }
        _ if name.starts_with("city45:") => {
            let n = parse_count(name, "city45", 10..=1_000_000)?;
            b.city(n as usize, PI / 4.0);
        }
        _ => return Ok(None),
    }
    let mut scene = b.into_scene(name)?;
    scene.study_frame = true;
    Ok(Some(scene))
}

/// The `N` of `{prefix}:N` (accepts `1e5`-style exponents), within `range`.
pub(super) fn parse_count(
    name: &str,
    prefix: &str,
    range: std::ops::RangeInclusive<u64>,
) -> Result<u64> {
    let text = &name[prefix.len() + 1..];
    let n = text.parse::<u64>().ok().or_else(|| {
        let f: f64 = text.parse().ok()?;
        (f.is_finite() && f.fract() == 0.0 && f >= 0.0 && f <= u64::MAX as f64).then_some(f as u64)
    });
    match n {
        Some(n) if range.contains(&n) => Ok(n),
        _ => Err(Error::usage(
            "SCENE",
            format!(
                "'{name}': N in {prefix}:N must be a whole number in {}..={}",
                range.start(),
                range.end()
            ),
        )),
    }
}

const WHITE: Vec3 = Vec3::new(0.725, 0.71, 0.68);
const RED: Vec3 = Vec3::new(0.63, 0.065, 0.05);
const GREEN: Vec3 = Vec3::new(0.14, 0.45, 0.091);

#[derive(Default)]
pub(super) struct Builder {
    pub(super) positions: Vec<Vec3>,
    pub(super) normals: Vec<Vec3>,
    triangles: Vec<[u32; 3]>,
    material_ids: Vec<u32>,
    materials: Vec<Material>,
}

impl Builder {
    pub(super) fn into_scene(self, name: &str) -> Result<Scene> {
        Scene::new(
            name,
            self.positions,
            Some(self.normals),
            self.triangles,
            self.material_ids,
            self.materials,
        )
    }

    pub(super) fn material(&mut self, m: Material) -> u32 {
        self.materials.push(m);
        self.materials.len() as u32 - 1
    }

    /// Adds a vertex; a zero normal means "use the geometric normal".
    fn vertex(&mut self, p: Vec3, n: Vec3) -> u32 {
        self.positions.push(p);
        self.normals.push(n);
        self.positions.len() as u32 - 1
    }

    pub(super) fn quad(&mut self, corners: [Vec3; 4], material: u32) {
        let i = corners.map(|p| self.vertex(p, Vec3::ZERO));
        self.triangles.push([i[0], i[1], i[2]]);
        self.triangles.push([i[0], i[2], i[3]]);
        self.material_ids.extend([material, material]);
    }

    fn cornell_box(&mut self) {
        let white = self.material(Material::diffuse("white", WHITE));
        let red = self.material(Material::diffuse("leftWall", RED));
        let green = self.material(Material::diffuse("rightWall", GREEN));
        let light = self.material(Material {
            ke: Vec3::new(17.0, 12.0, 4.0),
            ..Material::diffuse("light", Vec3::splat(0.78))
        });
        let v = |x, y, z| Vec3::new(x, y, z);
        self.quad(
            [
                v(-1., 0., 1.),
                v(1., 0., 1.),
                v(1., 0., -1.),
                v(-1., 0., -1.),
            ],
            white,
        );
        self.quad(
            [
                v(-1., 2., 1.),
                v(-1., 2., -1.),
                v(1., 2., -1.),
                v(1., 2., 1.),
            ],
            white,
        );
        self.quad(
            [
                v(-1., 0., -1.),
                v(1., 0., -1.),
                v(1., 2., -1.),
                v(-1., 2., -1.),
            ],
            white,
        );
        self.quad(
            [
                v(-1., 0., 1.),
                v(-1., 0., -1.),
                v(-1., 2., -1.),
                v(-1., 2., 1.),
            ],
            red,
        );
        self.quad(
            [v(1., 0., -1.), v(1., 0., 1.), v(1., 2., 1.), v(1., 2., -1.)],
            green,
        );
        let y = 1.98;
        self.quad(
            [
                v(-0.24, y, 0.16),
                v(-0.24, y, -0.22),
                v(0.23, y, -0.22),
                v(0.23, y, 0.16),
            ],
            light,
        );
    }

    /// A block standing on the floor: 6 faces (12 triangles) over a 4-corner
    /// footprint given as (x, z) pairs.
    fn block(&mut self, footprint: [[f32; 2]; 4], height: f32, material: u32) {
        let low = footprint.map(|[x, z]| Vec3::new(x, 0.0, z));
        let high = footprint.map(|[x, z]| Vec3::new(x, height, z));
        self.quad(high, material);
        self.quad(low, material);
        for i in 0..4 {
            let j = (i + 1) % 4;
            self.quad([low[i], low[j], high[j], high[i]], material);
        }
    }

    /// A UV sphere with smooth normals: `2 * slices * (stacks - 1)` triangles.
    pub(super) fn sphere(
        &mut self,
        center: Vec3,
        radius: f32,
        slices: u32,
        stacks: u32,
        material: u32,
    ) {
        let point = |stack: u32, slice: u32| {
            let theta = PI * stack as f32 / stacks as f32;
            let phi = 2.0 * PI * (slice % slices) as f32 / slices as f32;
            Vec3::new(
                theta.sin() * phi.cos(),
                theta.cos(),
                theta.sin() * phi.sin(),
            )
        };
        let top = self.vertex(center + Vec3::Y * radius, Vec3::Y);
        let bottom = self.vertex(center - Vec3::Y * radius, -Vec3::Y);
        // Rings 1..stacks-1, `slices` vertices each.
        let first = self.positions.len() as u32;
        for stack in 1..stacks {
            for slice in 0..slices {
                let n = point(stack, slice);
                self.vertex(center + n * radius, n);
            }
        }
        let ring = |stack: u32, slice: u32| first + (stack - 1) * slices + slice % slices;
        for slice in 0..slices {
            self.triangles
                .push([top, ring(1, slice + 1), ring(1, slice)]);
            self.triangles
                .push([bottom, ring(stacks - 1, slice), ring(stacks - 1, slice + 1)]);
            self.material_ids.extend([material, material]);
            for stack in 1..stacks - 1 {
                let (a, b) = (ring(stack, slice), ring(stack, slice + 1));
                let (c, d) = (ring(stack + 1, slice + 1), ring(stack + 1, slice));
                self.triangles.push([a, b, c]);
                self.triangles.push([a, c, d]);
                self.material_ids.extend([material, material]);
            }
        }
    }

    /// A UV sphere of about `n` triangles (stacks ~ sqrt(n / 4), twice as many
    /// slices) with its radius displaced by a sum of sines, standing in the box:
    /// the procedural mesh for build-time and throughput curves.
    fn displaced_sphere(&mut self, n: u64) {
        let material = self.material(Material::diffuse("mesh", Vec3::new(0.8, 0.75, 0.6)));
        let stacks = ((n as f64 / 4.0).sqrt().round() as u32).max(3);
        let slices = ((n as f64 / (2.0 * (stacks - 1) as f64)).round() as u32).max(3);
        let centre = Vec3::new(0.0, 0.75, -0.1);
        let first = self.positions.len();
        self.sphere(centre, 0.6, slices, stacks, material);
        // Displace along the normal; normals are left as the sphere's (shading only).
        for p in &mut self.positions[first..] {
            let d = (*p - centre).normalize_or_zero();
            let bump = 0.06 * (9.0 * d.x).sin() * (7.0 * d.y).cos() * (8.0 * d.z + 1.0).sin()
                + 0.02 * (31.0 * d.x + 17.0 * d.y).sin();
            *p = centre + d * (0.6 + bump);
        }
    }

    /// `n` grass blades on the floor: each one triangle 6 mm wide at its
    /// base and 0.3 to 0.9 tall, its tip leaning up to 0.4 of its height in
    /// a random direction. Long thin diagonal triangles: the boxes of any
    /// group of them overlap, which object splits cannot avoid and spatial
    /// splits can.
    fn grass(&mut self, n: usize) {
        let green = self.material(Material::diffuse("grass", Vec3::new(0.2, 0.5, 0.1)));
        let mut rng = crate::rng::Rng::for_pixel(0, 0x67_7261_7373, 1);
        for _ in 0..n {
            let mut u = || rng.next_f32();
            let base = Vec3::new(1.9 * u() - 0.95, 0.0, 1.9 * u() - 0.95);
            let height = 0.3 + 0.6 * u();
            let angle = 2.0 * PI * u();
            let lean = Vec3::new(angle.cos(), 0.0, angle.sin()) * 0.4 * height * u();
            let side = Vec3::new(-angle.sin(), 0.0, angle.cos()) * 0.003;
            let tip = base + lean + Vec3::Y * height;
            let i = [base - side, base + side, tip].map(|p| self.vertex(p, Vec3::ZERO));
            self.triangles.push(i);
            self.material_ids.push(green);
        }
    }

    /// A field of about `n` triangles in the plane y = 0: a k x k grid of
    /// quads 100 units across (k = ceil(sqrt(n / 2))), each inner vertex
    /// moved up to 0.3 of a cell in x and z, so no two triangles have the
    /// same shape; each quad split along an alternating diagonal. Lit by a
    /// 20 x 20 square facing down at y = 20 over the centre. Every box of
    /// any tree over it is flat in y.
    fn field(&mut self, n: usize) {
        let turf = self.material(Material::diffuse("turf", Vec3::new(0.3, 0.55, 0.25)));
        let light = self.material(Material {
            ke: Vec3::splat(4.0),
            ..Material::diffuse("sun", Vec3::splat(0.78))
        });
        let k = ((n as f64 / 2.0).sqrt().ceil() as usize).max(1);
        let cell = 100.0 / k as f32;
        let mut rng = crate::rng::Rng::for_pixel(0, 0x66_6965_6c64, 3);
        let first = self.positions.len() as u32;
        for j in 0..=k {
            for i in 0..=k {
                let inner = i > 0 && j > 0 && i < k && j < k;
                let (mut jx, mut jz) = (rng.next_f32() - 0.5, rng.next_f32() - 0.5);
                if !inner {
                    (jx, jz) = (0.0, 0.0);
                }
                let x = -50.0 + (i as f32 + 0.6 * jx) * cell;
                let z = -50.0 + (j as f32 + 0.6 * jz) * cell;
                self.vertex(Vec3::new(x, 0.0, z), Vec3::ZERO);
            }
        }
        let at = |i: usize, j: usize| first + (j * (k + 1) + i) as u32;
        for j in 0..k {
            for i in 0..k {
                let (a, b, c, d) = (at(i, j), at(i + 1, j), at(i + 1, j + 1), at(i, j + 1));
                // Wound to face +y (towards the light).
                if (i + j) % 2 == 0 {
                    self.triangles.extend([[a, c, b], [a, d, c]]);
                } else {
                    self.triangles.extend([[a, d, b], [b, d, c]]);
                }
                self.material_ids.extend([turf, turf]);
            }
        }
        let y = 20.0;
        self.quad(
            [
                Vec3::new(-10.0, y, -10.0),
                Vec3::new(10.0, y, -10.0),
                Vec3::new(10.0, y, 10.0),
                Vec3::new(-10.0, y, 10.0),
            ],
            light,
        );
    }

    /// An axis-aligned box from `lo` to `hi` (12 triangles, facing out).
    fn cuboid(&mut self, lo: Vec3, hi: Vec3, material: u32) {
        let footprint = [[lo.x, lo.z], [lo.x, hi.z], [hi.x, hi.z], [hi.x, lo.z]];
        let first = self.positions.len();
        self.block(footprint, hi.y - lo.y, material);
        for p in &mut self.positions[first..] {
            p.y += lo.y;
        }
    }

    /// A grid of k x k rooms 4 x 4 x 3 m (k from `n` at about 80 triangles a
    /// room), centred on the origin: each room has a floor, a ceiling with a
    /// 0.5 m light panel facing down, and walls 0.1 m thick on its -x and -z
    /// sides with a 1 m doorway (the grid closed on its +x and +z sides). The
    /// study's eye (0, 1, 3) stands in the room south of the centre one,
    /// looking through the doorway: long thin walls, many occluders.
    fn rooms(&mut self, n: usize) {
        let plaster = self.material(Material::diffuse("plaster", WHITE));
        let floor = self.material(Material::diffuse("floor", Vec3::new(0.55, 0.45, 0.35)));
        let panel = self.material(Material {
            ke: Vec3::splat(12.0),
            ..Material::diffuse("panel", Vec3::splat(0.78))
        });
        let k = ((n as f64 / 80.0).sqrt().ceil() as i32).max(1);
        let (size, height, wall, door) = (4.0f32, 3.0f32, 0.1f32, 0.5f32);
        let start = -(k / 2) as f32 * size - size / 2.0;
        for j in 0..k {
            for i in 0..k {
                let (x0, z0) = (start + i as f32 * size, start + j as f32 * size);
                let (x1, z1) = (x0 + size, z0 + size);
                let (cx, cz) = ((x0 + x1) / 2.0, (z0 + z1) / 2.0);
                // Floor faces up, ceiling and panel down.
                let at = |x: f32, y: f32, z: f32| Vec3::new(x, y, z);
                self.quad(
                    [
                        at(x0, 0.0, z0),
                        at(x0, 0.0, z1),
                        at(x1, 0.0, z1),
                        at(x1, 0.0, z0),
                    ],
                    floor,
                );
                self.quad(
                    [
                        at(x0, height, z0),
                        at(x1, height, z0),
                        at(x1, height, z1),
                        at(x0, height, z1),
                    ],
                    plaster,
                );
                let (h, r) = (height - 0.01, 0.25);
                self.quad(
                    [
                        at(cx - r, h, cz - r),
                        at(cx + r, h, cz - r),
                        at(cx + r, h, cz + r),
                        at(cx - r, h, cz + r),
                    ],
                    panel,
                );
                // The -z and -x walls, each with a doorway 2.2 m high at its middle.
                let lintel = 2.2;
                self.cuboid(at(x0, 0.0, z0), at(cx - door, height, z0 + wall), plaster);
                self.cuboid(at(cx + door, 0.0, z0), at(x1, height, z0 + wall), plaster);
                self.cuboid(
                    at(cx - door, lintel, z0),
                    at(cx + door, height, z0 + wall),
                    plaster,
                );
                self.cuboid(at(x0, 0.0, z0), at(x0 + wall, height, cz - door), plaster);
                self.cuboid(at(x0, 0.0, cz + door), at(x0 + wall, height, z1), plaster);
                self.cuboid(
                    at(x0, lintel, cz - door),
                    at(x0 + wall, height, cz + door),
                    plaster,
                );
                if i == k - 1 {
                    self.cuboid(at(x1 - wall, 0.0, z0), at(x1, height, z1), plaster);
                }
                if j == k - 1 {
                    self.cuboid(at(x0, 0.0, z1 - wall), at(x1, height, z1), plaster);
                }
            }
        }
    }

    /// About `n` triangles of pipes: cylinders of radius 0.01-0.1 and length
    /// 2-10 at random orientations in a 10-unit cube, each of 12 sides in
    /// one segment (two long slivers a side) with fan caps: 48 triangles.
    fn pipes(&mut self, n: usize) {
        let steel = self.material(Material::diffuse("steel", Vec3::new(0.6, 0.62, 0.66)));
        let mut rng = crate::rng::Rng::for_pixel(0, 0x7069_7065, 4);
        const SIDES: usize = 12;
        for _ in 0..n.div_ceil(4 * SIDES) {
            let mut u = || rng.next_f32();
            let start = Vec3::new(u(), u(), u()) * 10.0 - 5.0;
            let axis = Vec3::new(u() - 0.5, u() - 0.5, u() - 0.5).normalize_or(Vec3::X);
            let (length, radius) = (2.0 + 8.0 * u(), 0.01 + 0.09 * u());
            let side = axis.any_orthonormal_vector();
            let other = axis.cross(side);
            let ring = |at: Vec3| -> Vec<Vec3> {
                (0..SIDES)
                    .map(|i| {
                        let a = 2.0 * PI * i as f32 / SIDES as f32;
                        at + (side * a.cos() + other * a.sin()) * radius
                    })
                    .collect()
            };
            let end = start + axis * length;
            let (a, b) = (ring(start), ring(end));
            for i in 0..SIDES {
                let j = (i + 1) % SIDES;
                self.quad([a[i], a[j], b[j], b[i]], steel);
            }
            for (ring, centre) in [(&a, start), (&b, end)] {
                let c = self.vertex(centre, Vec3::ZERO);
                for i in 0..SIDES {
                    let p = self.vertex(ring[i], Vec3::ZERO);
                    let q = self.vertex(ring[(i + 1) % SIDES], Vec3::ZERO);
                    self.triangles.push([c, p, q]);
                    self.material_ids.push(steel);
                }
            }
        }
    }

    /// `n` triangles of 1 to 4 units across with random vertices around
    /// random centres in a 4-unit cube: they cross one another everywhere.
    fn overlap(&mut self, n: usize) {
        let paint = self.material(Material::diffuse("paint", Vec3::new(0.7, 0.4, 0.3)));
        let mut rng = crate::rng::Rng::for_pixel(0, 0x6f76_6572, 5);
        for _ in 0..n {
            let mut u = || rng.next_f32();
            let centre = Vec3::new(u(), u(), u()) * 4.0 - 2.0;
            let size = 1.0 + 3.0 * u();
            let mut corner = || centre + Vec3::new(u() - 0.5, u() - 0.5, u() - 0.5) * size;
            let tri = [corner(), corner(), corner()];
            let i = tri.map(|p| self.vertex(p, Vec3::ZERO));
            self.triangles.push(i);
            self.material_ids.push(paint);
        }
    }

    /// `n` boxes standing on the floor, footprints 2 mm to 0.5 wide
    /// (log-uniform) and heights 0.5 to 2.5 times that, on a 40 x 40 ground
    /// plane just under the floor (hidden by it, but the tree must hold
    /// it); the whole city turned by `turn` about the vertical axis. Small
    /// detail in a huge box ("teapot in a stadium"); turned, every wall is
    /// diagonal.
    fn city(&mut self, n: usize, turn: f32) {
        let concrete = self.material(Material::diffuse("city", Vec3::new(0.6, 0.6, 0.65)));
        let ground = self.material(Material::diffuse("ground", Vec3::splat(0.4)));
        let first = self.positions.len();
        let mut rng = crate::rng::Rng::for_pixel(0, 0x6369_7479, 2);
        for _ in 0..n {
            let mut u = || rng.next_f32();
            let size = 0.002 * 250f32.powf(u());
            let height = size * (0.5 + 2.0 * u());
            let (x, z) = (1.8 * u() - 0.9, 1.8 * u() - 0.9);
            let h = size * 0.5;
            self.block(
                [
                    [x - h, z - h],
                    [x + h, z - h],
                    [x + h, z + h],
                    [x - h, z + h],
                ],
                height,
                concrete,
            );
        }
        let y = -0.001;
        self.quad(
            [
                Vec3::new(-20.0, y, 20.0),
                Vec3::new(20.0, y, 20.0),
                Vec3::new(20.0, y, -20.0),
                Vec3::new(-20.0, y, -20.0),
            ],
            ground,
        );
        let (sin, cos) = turn.sin_cos();
        for p in &mut self.positions[first..] {
            *p = Vec3::new(cos * p.x - sin * p.z, p.y, sin * p.x + cos * p.z);
        }
    }

    /// The two glossy spheres of the McGuire sphere scene (same places, sizes and
    /// materials): 2 x 1088 triangles.
    fn spheres(&mut self) {
        let mirror = self.material(Material {
            ks: Vec3::splat(0.95),
            ns: 1000.0,
            ..Material::diffuse("leftSphere", Vec3::splat(0.01))
        });
        let glossy = self.material(Material {
            ks: Vec3::splat(0.3),
            ns: 200.0,
            ..Material::diffuse("rightSphere", Vec3::splat(0.01))
        });
        self.sphere(Vec3::new(-0.42, 0.33, -0.28), 0.32, 32, 18, mirror);
        self.sphere(Vec3::new(0.45, 0.33, 0.38), 0.32, 32, 18, glossy);
    }

    /// A wavy height-field water surface over the whole floor: a 70 x 35 grid of
    /// quads (4900 triangles) with analytic normals.
    fn water(&mut self) {
        let water = self.material(Material {
            ks: Vec3::splat(0.3),
            ns: 200.0,
            ..Material::diffuse("water", Vec3::new(0.02, 0.04, 0.06))
        });
        let (nx, nz) = (70u32, 35u32);
        // Height and its gradient: two sums of sines, about 0.2 +- 0.05.
        let height = |x: f32, z: f32| {
            0.2 + 0.03 * (6.0 * x + 1.0).sin() * (5.0 * z).cos()
                + 0.015 * (13.0 * x + 9.0 * z).sin()
        };
        let gradient = |x: f32, z: f32| {
            let dx =
                0.18 * (6.0 * x + 1.0).cos() * (5.0 * z).cos() + 0.195 * (13.0 * x + 9.0 * z).cos();
            let dz = -0.15 * (6.0 * x + 1.0).sin() * (5.0 * z).sin()
                + 0.135 * (13.0 * x + 9.0 * z).cos();
            (dx, dz)
        };
        let first = self.positions.len() as u32;
        for iz in 0..=nz {
            for ix in 0..=nx {
                let x = -1.0 + 2.0 * ix as f32 / nx as f32;
                let z = -1.0 + 2.0 * iz as f32 / nz as f32;
                let (dx, dz) = gradient(x, z);
                self.vertex(
                    Vec3::new(x, height(x, z), z),
                    Vec3::new(-dx, 1.0, -dz).normalize(),
                );
            }
        }
        let at = |ix: u32, iz: u32| first + iz * (nx + 1) + ix;
        for iz in 0..nz {
            for ix in 0..nx {
                let (a, b) = (at(ix, iz), at(ix + 1, iz));
                let (c, d) = (at(ix + 1, iz + 1), at(ix, iz + 1));
                self.triangles.push([a, b, c]);
                self.triangles.push([a, c, d]);
                self.material_ids.extend([water, water]);
            }
        }
    }
}

/// A ground for the instanced built-ins: one quad `half` units to each side
/// of the origin in y = 0, as a mesh of its own (placed once).
pub(super) fn ground(half: f32, colour: Vec3) -> Result<Scene> {
    let mut b = Builder::default();
    let soil = b.material(Material::diffuse("ground", colour));
    let c = |x: f32, z: f32| Vec3::new(x * half, 0.0, z * half);
    b.quad(
        [c(-1.0, 1.0), c(1.0, 1.0), c(1.0, -1.0), c(-1.0, -1.0)],
        soil,
    );
    b.into_scene("ground")
}
