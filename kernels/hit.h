/* The shading point of a camera ray's hit, as wavlight/raytrace.py makes it: the face normal
 * turned towards the viewer, the point, and the shadow-ray offset max(OFFSET_RELATIVE |p|_inf,
 * the face's offset floor, the eye's) along that normal. numpy twin: RayTracer.surface. */
#ifndef WAVLIGHT_HIT_H
#define WAVLIGHT_HIT_H

#ifndef OFFSET_RELATIVE
#define OFFSET_RELATIVE 1e-4   /* shadow-ray offset per unit of |p|: the host passes wavlight.raytrace's */
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

#endif
