/* The shading point of a camera ray's hit, as wavlight/raytrace.py makes it: the face normal
 * turned towards the viewer, the point, and the shadow-ray offset max(OFFSET_RELATIVE |p|_inf,
 * the face's offset floor, the eye's) along that normal (numpy twin: RayTracer.surface); and the
 * shading normal interpolated from the face's corner normals (numpy twin: RayTracer.hit;
 * docs/decisions/shading-normals.md). */
#ifndef WAVLIGHT_HIT_H
#define WAVLIGHT_HIT_H

#ifndef OFFSET_RELATIVE
#define OFFSET_RELATIVE 1e-4   /* shadow-ray offset per unit of |p|: the host passes wavlight.raytrace's */
#endif
#ifndef SMOOTH_MIN_LENGTH2
#define SMOOTH_MIN_LENGTH2 1e-12f   /* wavlight.raytrace.SMOOTH_MIN_LENGTH2 */
#endif

/* Rays from the eye in directions d reaching faces f (rows of face_normal: the normal, the
 * offset floor) at distance t: normal n (towards the viewer), point p and offset eps. */
INLINE void hit_point(const realv dx, const realv dy, const realv dz, const realv t, const uintv f,
                      __global const float *face_normal, const float eye_x, const float eye_y,
                      const float eye_z, const float eye_offset, realv *nx, realv *ny, realv *nz,
                      realv *px, realv *py, realv *pz, realv *eps)
{
    realv offset_floor;
    GATHER4(face_normal, 4 * f, nx, ny, nz, &offset_floor);
    const realv flip = select((realv)1.0f, (realv)-1.0f, *nx * dx + *ny * dy + *nz * dz > 0.0f);
    *nx *= flip;
    *ny *= flip;
    *nz *= flip;
    *px = eye_x + dx * t;
    *py = eye_y + dy * t;
    *pz = eye_z + dz * t;
    const realv size = fmax(fmax(fabs(*px), fabs(*py)), fabs(*pz));
    *eps = fmax(fmax((float)OFFSET_RELATIVE * size, offset_floor), eye_offset);
}

/* The shading normal of rays along d hitting faces f at embree's barycentrics (u, v):
 * normalize((1 - u - v) n0 + u n1 + v n2) of the rows of normals (3 floats each) that the face's
 * three corners name (corner: 3 ints per face), turned towards the viewer; the geometric normal
 * (gx, gy, gz) where that sum is (nearly) zero (a flat face's corners name a row of zeros). */
INLINE void shading_normal(const realv dx, const realv dy, const realv dz, const realv u, const realv v,
                           const uintv f, __global const int *corner, __global const float *normals,
                           const realv gx, const realv gy, const realv gz, realv *nx, realv *ny, realv *nz)
{
    const uintv c0 = as_uintv(GATHER_INT(corner, 3 * f)), c1 = as_uintv(GATHER_INT(corner, 3 * f + 1));
    const uintv c2 = as_uintv(GATHER_INT(corner, 3 * f + 2));
    realv ax, ay, az, bx, by, bz, cx, cy, cz;
    GATHER3(normals, 3 * c0, &ax, &ay, &az);
    GATHER3(normals, 3 * c1, &bx, &by, &bz);
    GATHER3(normals, 3 * c2, &cx, &cy, &cz);
    const realv w = 1.0f - u - v;
    realv x = w * ax + u * bx + v * cx, y = w * ay + u * by + v * cy, z = w * az + u * bz + v * cz;
    const realv length2 = x * x + y * y + z * z;
    const intv ok = length2 > SMOOTH_MIN_LENGTH2;
    const realv length = sqrt(select((realv)1.0f, length2, ok));
    x = select(gx, x / length, ok);
    y = select(gy, y / length, ok);
    z = select(gz, z / length, ok);
    const realv flip = select((realv)1.0f, (realv)-1.0f, x * dx + y * dy + z * dz > 0.0f);
    *nx = x * flip;
    *ny = y * flip;
    *nz = z * flip;
}

#endif
