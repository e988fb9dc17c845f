//! Force assembly of the explicit solver: every force term of the model, accumulated per
//! particle for a block of lanes. Adding a force term means adding one function here and calling
//! it from the half of the force evaluation it belongs to ([`membrane_forces`] or
//! [`contact_and_bending_forces`]).

use crate::constants::StepConstants;
use crate::forces::{self, ContactMaterial};
use crate::math::{get3, set3, Lanes, Real, V3};
use crate::model::{BendingEdge, Model, Triangle};
use crate::solvers::across_elements::{gather_elements, gather_triangle_rest, E8, ELEMENT_LANES};
use crate::state::{LaneDisc, LaneParams, LaneSpring};

type L<const W: usize> = Lanes<W>;

/// [`membrane_forces`] compiled for AVX2 when the CPU has it.
pub(super) fn membrane_forces_simd<const W: usize>(
    model: &Model,
    x: &[V3<L<W>>],
    v: &[V3<L<W>>],
    springs: &[LaneSpring<W>],
    spring_force: &mut [V3<L<W>>],
    p: &LaneParams<W>,
    f: &mut [V3<L<W>>],
) {
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn avx2<const W: usize>(
        model: &Model,
        x: &[V3<L<W>>],
        v: &[V3<L<W>>],
        springs: &[LaneSpring<W>],
        spring_force: &mut [V3<L<W>>],
        p: &LaneParams<W>,
        f: &mut [V3<L<W>>],
    ) {
        membrane_forces(model, x, v, springs, spring_force, p, f)
    }
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2, checked just above.
            return unsafe { avx2(model, x, v, springs, spring_force, p, f) };
        }
    }
    membrane_forces(model, x, v, springs, spring_force, p, f)
}

/// [`contact_and_bending_forces`] compiled for AVX2 when the CPU has it.
#[allow(clippy::too_many_arguments)]
pub(super) fn contact_and_bending_forces_simd<const W: usize>(
    model: &Model,
    k: &StepConstants,
    refresh: Option<L<W>>,
    x: &[V3<L<W>>],
    v: &[V3<L<W>>],
    disc: &LaneDisc<W>,
    p: &LaneParams<W>,
    contact_point: &mut [V3<L<W>>],
    contact_normal: &mut [V3<L<W>>],
    f: &mut [V3<L<W>>],
) -> (V3<L<W>>, V3<L<W>>) {
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    #[allow(clippy::too_many_arguments)]
    unsafe fn avx2<const W: usize>(
        model: &Model,
        k: &StepConstants,
        refresh: Option<L<W>>,
        x: &[V3<L<W>>],
        v: &[V3<L<W>>],
        disc: &LaneDisc<W>,
        p: &LaneParams<W>,
        cp: &mut [V3<L<W>>],
        cn: &mut [V3<L<W>>],
        f: &mut [V3<L<W>>],
    ) -> (V3<L<W>>, V3<L<W>>) {
        contact_and_bending_forces(model, k, refresh, x, v, disc, p, cp, cn, f)
    }
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2, checked just above.
            return unsafe {
                avx2(
                    model,
                    k,
                    refresh,
                    x,
                    v,
                    disc,
                    p,
                    contact_point,
                    contact_normal,
                    f,
                )
            };
        }
    }
    contact_and_bending_forces(
        model,
        k,
        refresh,
        x,
        v,
        disc,
        p,
        contact_point,
        contact_normal,
        f,
    )
}

/// Attachment springs, membrane triangles and part of the bending, accumulated into `f`
/// (cleared first).
#[inline(always)]
pub(super) fn membrane_forces<const W: usize>(
    model: &Model,
    x: &[V3<L<W>>],
    v: &[V3<L<W>>],
    springs: &[LaneSpring<W>],
    spring_force: &mut [V3<L<W>>],
    p: &LaneParams<W>,
    f: &mut [V3<L<W>>],
) {
    let cup_start = model.cup_start();
    for fi in f.iter_mut() {
        *fi = V3::zero();
    }

    // 2. Attachment springs (per-lane package vertex: gather/scatter by lane).
    for (c, spring) in springs.iter().enumerate() {
        let i = cup_start + c;
        let mut xj = V3::<L<W>>::zero();
        let mut vj = V3::<L<W>>::zero();
        for l in 0..W {
            let j = spring.target[l] as usize;
            set3(&mut xj, l, get3(&x[j], l));
            set3(&mut vj, l, get3(&v[j], l));
        }
        let fi = forces::spring(x[i], xj, v[i], vj, spring.rest, p.spring[0], p.spring[1]);
        // A lip element that let go transmits nothing.
        let fi = V3::select_lt(L::splat(0.5), spring.sealed, fi, V3::zero());
        spring_force[c] = fi;
        f[i] += fi;
        for l in 0..W {
            let j = spring.target[l] as usize;
            let g = get3(&fi, l);
            f[j].x.0[l] -= g[0];
            f[j].y.0[l] -= g[1];
            f[j].z.0[l] -= g[2];
        }
    }

    // 3. Membrane triangles.
    for (tris, mat) in [
        (&model.package_triangles[..], p.tri),
        (&model.cup_triangles[..], p.cup_tri),
    ] {
        triangle_forces(tris, mat, x, v, f);
    }

    // 4. Bending, first part of the package edges.
    let split = bending_split(model);
    bending_forces(&model.package_edges[..split], p.edge, x, v, f);
}

/// Bending of `edges` with material `mat` (ke, kd), accumulated into `f`.
#[inline(always)]
fn bending_forces<const W: usize>(
    edges: &[BendingEdge],
    mat: [L<W>; 2],
    x: &[V3<L<W>>],
    v: &[V3<L<W>>],
    f: &mut [V3<L<W>>],
) {
    if W == 1 {
        return bending_across_elements(edges, [mat[0].0[0], mat[1].0[0]], x, v, f);
    }
    for e in edges {
        let id = e.idx.map(|i| i as usize);
        let rest = L::splat(e.rest_angle);
        let fs = forces::bending(id.map(|i| x[i]), id.map(|i| v[i]), rest, mat[0], mat[1]);
        // Written out, not an iterator over the four (see the block-descent bending).
        f[id[0]] += fs[0];
        f[id[1]] += fs[1];
        f[id[2]] += fs[2];
        f[id[3]] += fs[3];
    }
}

/// Membrane triangles with material `mat` (k_mu, k_lambda, k_damp), accumulated into `f`.
#[inline(always)]
fn triangle_forces<const W: usize>(
    tris: &[Triangle],
    mat: [L<W>; 3],
    x: &[V3<L<W>>],
    v: &[V3<L<W>>],
    f: &mut [V3<L<W>>],
) {
    if W == 1 {
        return triangles_across_elements(tris, mat.map(|m| m.0[0]), x, v, f);
    }
    for tri in tris {
        let [a, b, c] = tri.idx.map(|i| i as usize);
        let dm = tri.rest.dm_splat();
        let inv_area = L::splat(tri.rest.inv_rest_area());
        let fs = forces::triangle(
            [x[a], x[b], x[c]],
            [v[a], v[b], v[c]],
            dm,
            inv_area,
            mat[0],
            mat[1],
            mat[2],
        );
        f[a] += fs[0];
        f[b] += fs[1];
        f[c] += fs[2];
    }
}

/// Single-environment blocks (lane 0 only): triangles [`ELEMENT_LANES`] at a time, SIMD across
/// elements. Each element's arithmetic is the same as in the per-environment path and the forces
/// are added in the same element order, so results are bit-identical.
#[inline(always)]
fn triangles_across_elements<const W: usize>(
    tris: &[Triangle],
    mat: [f32; 3],
    x: &[V3<L<W>>],
    v: &[V3<L<W>>],
    f: &mut [V3<L<W>>],
) {
    let mat = mat.map(E8::splat);
    for chunk in tris.chunks(ELEMENT_LANES) {
        let (xs, vs) = gather_elements(chunk.len(), |e| chunk[e].idx, x, v);
        let (dm, inv_area) = gather_triangle_rest(chunk);
        let fs = forces::triangle(xs, vs, dm, inv_area, mat[0], mat[1], mat[2]);
        for (e, tri) in chunk.iter().enumerate() {
            for (corner, &i) in tri.idx.iter().enumerate() {
                add_lane(&mut f[i as usize], get3(&fs[corner], e));
            }
        }
    }
}

/// Single-environment blocks: bending elements [`ELEMENT_LANES`] at a time (see
/// [`triangles_across_elements`]).
#[inline(always)]
fn bending_across_elements<const W: usize>(
    edges: &[BendingEdge],
    mat: [f32; 2],
    x: &[V3<L<W>>],
    v: &[V3<L<W>>],
    f: &mut [V3<L<W>>],
) {
    let mat = mat.map(E8::splat);
    for chunk in edges.chunks(ELEMENT_LANES) {
        let (xs, vs) = gather_elements(chunk.len(), |e| chunk[e].idx, x, v);
        let rest = Lanes(std::array::from_fn(|e| {
            chunk[e.min(chunk.len() - 1)].rest_angle
        }));
        let fs = forces::bending(xs, vs, rest, mat[0], mat[1]);
        for (e, edge) in chunk.iter().enumerate() {
            for (corner, &i) in edge.idx.iter().enumerate() {
                add_lane(&mut f[i as usize], get3(&fs[corner], e));
            }
        }
    }
}

/// `f += g` on lane 0, component by component (the same additions as `V3 += V3`).
#[inline(always)]
fn add_lane<const W: usize>(f: &mut V3<L<W>>, g: [f32; 3]) {
    f.x.0[0] += g[0];
    f.y.0[0] += g[1];
    f.z.0[0] += g[2];
}

/// Package bending edges before this index go with the membrane half of the force evaluation,
/// the rest with the contact half (balances the two threads of a single-environment batch).
fn bending_split(model: &Model) -> usize {
    model.package_edges.len() * 3 / 8
}

/// The rest of the bending, ground and disc contacts, accumulated into `f` (cleared first). Returns the force
/// and torque on the disc.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(super) fn contact_and_bending_forces<const W: usize>(
    model: &Model,
    k: &StepConstants,
    refresh: Option<L<W>>,
    x: &[V3<L<W>>],
    v: &[V3<L<W>>],
    disc: &LaneDisc<W>,
    p: &LaneParams<W>,
    contact_point: &mut [V3<L<W>>],
    contact_normal: &mut [V3<L<W>>],
    f: &mut [V3<L<W>>],
) -> (V3<L<W>>, V3<L<W>>) {
    let zero = L::<W>::splat(0.0);
    let n = model.num_particles();
    let cup_start = model.cup_start();
    let disc = *disc;
    for fi in f.iter_mut() {
        *fi = V3::zero();
    }
    // 4. Bending (the remaining package edges, then the cups).
    let split = bending_split(model);
    bending_forces(&model.package_edges[split..], p.edge, x, v, f);
    let cup_edge = [
        L::splat(model.config.cups.edge_ke),
        L::splat(model.config.cups.edge_kd),
    ];
    bending_forces(&model.cup_edges, cup_edge, x, v, f);

    // 5. Particle-ground contact.
    let radius = model.particle_radius;
    let rad = L::<W>::splat(radius);
    let ground = ContactMaterial {
        ke: L::splat(k.ground.ke),
        kd: L::splat(k.ground.kd),
        kf: L::splat(k.ground.kf),
        mu: L::splat(k.ground.mu),
    };
    for i in 0..n {
        if x[i].y.0.iter().all(|&y| y >= radius) {
            continue;
        }
        let fg = forces::particle_ground(x[i], v[i], rad, ground);
        f[i] = V3::select_lt(x[i].y - rad, zero, f[i] + fg, f[i]);
    }

    // 6. Disc: ground contact at its rim points, then particle contacts.
    let mut disc_f = V3::<L<W>>::zero();
    let mut disc_t = V3::<L<W>>::zero();
    let shape_thickness = L::splat(model.config.disc.shape_thickness_m);
    for rp in &model.disc.rim_points {
        let r = disc.q.rotate(V3::splat(*rp));
        let point = disc.com + r;
        if point
            .y
            .0
            .iter()
            .all(|&y| y >= model.config.disc.shape_thickness_m)
        {
            continue;
        }
        let vel = disc.v + disc.w.cross(r);
        let fr = forces::rigid_ground(point, vel, shape_thickness, p.disc_ground);
        let touching = point.y - shape_thickness;
        disc_f = V3::select_lt(touching, zero, disc_f + fr, disc_f);
        disc_t = V3::select_lt(touching, zero, disc_t + r.cross(fr), disc_t);
    }
    let (dr, dh) = (model.disc.radius, model.disc.half_height);
    if let Some(due) = refresh {
        // Warp's `collide()`: closest point (body frame) and normal (world), frozen until
        // the next refresh of each lane's own clock.
        let (disc_r, disc_h) = (L::splat(dr), L::splat(dh));
        let half = L::splat(0.5);
        for i in 0..n {
            let local = disc.q.rotate_inv(x[i] - disc.com);
            let (d, n_local) = forces::cylinder_distance(local, disc_r, disc_h);
            let point = local - n_local * d;
            let normal = disc.q.rotate(n_local);
            contact_point[i] = V3::select_lt(half, due, point, contact_point[i]);
            contact_normal[i] = V3::select_lt(half, due, normal, contact_normal[i]);
        }
    }
    // Only particles that can touch the disc (bounding sphere) are evaluated; beyond it a
    // frozen contact plane could only produce a spurious long-range force.
    let reach = (dr * dr + dh * dh).sqrt() + radius;
    let reach2 = reach * reach;
    let colliding = if model.config.cups.collide_with_disc {
        n
    } else {
        cup_start
    };
    for i in 0..colliding {
        let rel = x[i] - disc.com;
        let dist2 = rel.dot(rel);
        if dist2.0.iter().all(|&d| d > reach2) {
            continue;
        }
        let normal = contact_normal[i];
        let bx = disc.com + disc.q.rotate(contact_point[i]);
        let (fp, arm) = forces::particle_disc(
            x[i],
            v[i],
            rad,
            normal,
            bx,
            disc.com,
            disc.v,
            disc.w,
            p.disc_contact,
        );
        let gap = normal.dot(x[i] - bx) - rad;
        let near = L::select_lt(L::splat(reach2), dist2, zero, L::splat(1.0));
        let gap = L::select_lt(zero, near, gap, L::splat(1.0));
        f[i] = V3::select_lt(zero, gap, f[i], f[i] + fp);
        disc_f = V3::select_lt(zero, gap, disc_f, disc_f - fp);
        disc_t = V3::select_lt(zero, gap, disc_t, disc_t - arm.cross(fp));
    }
    (disc_f, disc_t)
}
