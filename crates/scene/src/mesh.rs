//! Indexed triangle meshes, the form every scene source produces.

use geom::{Aabb, Triangle, Vec3};

/// An indexed triangle mesh in world space. Triangle `i` is `triangles[i]`; where a scene's
/// topology is stable, `i` is the primitive's id in every frame.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Vertex indices of each triangle (all `< positions.len()`).
    pub triangles: Vec<[u32; 3]>,
    /// Material id of each triangle (same length as `triangles`); index into
    /// `material_names`.
    pub material_ids: Vec<u32>,
    /// Material (or group) names, in order of first appearance. May be empty when the
    /// source has no materials, in which case every id is 0.
    pub material_names: Vec<String>,
}

impl Mesh {
    /// A mesh without materials (every triangle has material id 0).
    pub fn new(positions: Vec<Vec3>, triangles: Vec<[u32; 3]>) -> Self {
        let material_ids = vec![0; triangles.len()];
        Mesh {
            positions,
            triangles,
            material_ids,
            material_names: Vec::new(),
        }
    }

    /// Number of triangles.
    #[inline]
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// Triangle `i` with its vertices resolved.
    #[inline]
    pub fn triangle(&self, i: usize) -> Triangle {
        let [a, b, c] = self.triangles[i];
        Triangle::new(
            self.positions[a as usize],
            self.positions[b as usize],
            self.positions[c as usize],
        )
    }

    /// All triangles with vertices resolved, in primitive-id order.
    pub fn triangles_iter(&self) -> impl ExactSizeIterator<Item = Triangle> + '_ {
        (0..self.triangles.len()).map(|i| self.triangle(i))
    }

    /// The centroid (vertex mean) of every triangle, in primitive-id order: the points of
    /// the point-tree modes.
    pub fn centroids(&self) -> Vec<Vec3> {
        self.triangles
            .iter()
            .map(|t| t.iter().map(|&v| self.positions[v as usize]).sum::<Vec3>() / 3.0)
            .collect()
    }

    /// Bounding box of the referenced vertices (empty for an empty mesh).
    pub fn bounds(&self) -> Aabb {
        self.triangles
            .iter()
            .flat_map(|t| t.iter())
            .fold(Aabb::EMPTY, |b, &i| b.grow(self.positions[i as usize]))
    }

    /// Number of zero-area triangles (they are kept; see the crate's NaN policy).
    pub fn degenerate_count(&self) -> usize {
        self.triangles_iter().filter(|t| t.is_degenerate()).count()
    }

    /// Checks the invariants: indices in range, one material id per triangle and each id
    /// in range of `material_names` (or 0 when there are no names).
    pub fn check(&self) -> Result<(), String> {
        let n = self.positions.len();
        if let Some((i, t)) = self
            .triangles
            .iter()
            .enumerate()
            .find(|(_, t)| t.iter().any(|&v| v as usize >= n))
        {
            return Err(format!(
                "triangle {i} has index out of range: {t:?} (vertices: {n})"
            ));
        }
        if self.material_ids.len() != self.triangles.len() {
            return Err(format!(
                "{} material ids for {} triangles",
                self.material_ids.len(),
                self.triangles.len()
            ));
        }
        let names = self.material_names.len().max(1);
        if let Some(&m) = self.material_ids.iter().find(|&&m| m as usize >= names) {
            return Err(format!("material id {m} out of range ({names} materials)"));
        }
        Ok(())
    }
}

/// A mesh read from one file, with what the loader had to do to it.
#[derive(Clone, Debug, Default)]
pub struct LoadedMesh {
    /// The mesh.
    pub mesh: Mesh,
    /// Triangles dropped because they referenced a vertex with a NaN or infinite coordinate.
    pub dropped_triangles: usize,
    /// Faces with more than three vertices that were triangulated (as fans).
    pub polygons_triangulated: usize,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bounds_and_check() {
        let m = Mesh {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::splat(100.0)],
            triangles: vec![[0, 1, 2]],
            material_ids: vec![0],
            material_names: vec![],
        };
        // The unreferenced vertex at 100 does not count.
        assert_eq!(m.bounds(), Aabb::new(Vec3::ZERO, Vec3::new(1.0, 1.0, 0.0)));
        assert!(m.check().is_ok());
        let mut bad = m.clone();
        bad.triangles.push([0, 1, 4]);
        bad.material_ids.push(0);
        assert!(bad.check().unwrap_err().contains("out of range"));
    }
}
