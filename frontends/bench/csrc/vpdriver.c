/*
 * vpdriver.c: the VolPack side of shearwarp-bench.
 *
 * Builds a VolPack context for one 8-bit volume with the benchmark's transfer functions
 * and lighting, times preprocessing (normals + classification into VolPack's run-length
 * encoded volume) and renders frames of it, each timed with clock_gettime. Images are
 * returned to Rust as RGB8, row 0 at the top.
 *
 * How the benchmark's model maps onto VolPack's API:
 *   - Opacity: one classification table indexed by the scalar (VolPack corrects it for
 *     the viewing direction per frame, like shearwarp).
 *   - Colour: shearwarp shades a voxel as min(1, C(s)*(ka + kd*|n.L|) + ks*|n.H|^e) with
 *     C(s) a piecewise-linear colour transfer function. VolPack's lookup shader sums
 *     per-material Phong colours weighted by a table indexed by a voxel field, so each
 *     colour breakpoint becomes a material (ambient ka*C_m, diffuse kd*C_m, specular ks)
 *     and the weight table holds the piecewise-linear "hat" weights of the scalar.
 *   - Lighting: one directional light given in camera space while the model matrix is
 *     the identity, two-sided (VP_LIGHT_BOTH_SIDES), white. Voxels without a gradient
 *     get ambient + diffuse (VolPack's own table gives them ambient only).
 *   - View: VolPack maps index point p to (p - n/2)/maxdim, then MODEL, VIEW, PROJECT and
 *     a viewport that spans [-1, 1] over the image. MODEL = Rx(rx)*Ry(ry)*S (S the
 *     relative voxel spacing), VIEW translates by half a voxel so that voxel centres sit
 *     at (p - (n-1)/2) as in shearwarp's convention, and PROJECT is an orthographic
 *     window whose shorter side spans the volume's diagonal.
 */

#include <math.h>
#include <stddef.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include <volpack.h>

#define VPB_VALUES 256
#define VPB_NORMALS (VP_NORM_MAX + 1)
#define VPB_PI 3.14159265358979323846

/* Driver errors, besides VolPack's own codes (>= 1000). */
#define VPB_ERR_PARAMS (-1)
#define VPB_ERR_MEMORY (-2)
#define VPB_ERR_CONTEXT (-3)

typedef struct {
    unsigned short normal; /* encoded normal (field 0, shading colour index) */
    unsigned char scalar;  /* raw value (field 1, classification and material weights) */
    unsigned char unused;
} VpbVoxel;

enum { FIELD_NORMAL = 0, FIELD_SCALAR = 1 };

/* Everything the Rust side passes in; mirrored by `VpbParams` in src/volpack.rs. */
typedef struct {
    int dims[3];
    double spacing[3];
    const float *opacity; /* VPB_VALUES entries, 0..1 */
    double min_opacity;
    int materials;
    const float *material_rgb; /* materials * 3, 0..1 */
    const float *weights;      /* VPB_VALUES * materials */
    double ka, kd, ks, shininess;
    double light[3]; /* toward the light, camera space */
    double max_ray_opacity;
    double pixel_offset[2]; /* extra image-space shift, pixels (x right, y down) */
} VpbParams;

typedef struct {
    vpContext *vpc;
    VpbVoxel *voxels;
    float *shade_table;
    float *weights;
    float opacity[VPB_VALUES];
    int dims[3];
    double rel_spacing[3];
    double pixel_offset[2];
    int materials;
    float zero_normal[VP_MAX_MATERIAL][3]; /* shade of a voxel without a gradient */
    unsigned char *image;
    int width, height;
} VpbScene;

static double now_ms(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (double)t.tv_sec * 1e3 + (double)t.tv_nsec * 1e-6;
}

const char *vpb_error_string(int code)
{
    switch (code) {
    case VPB_ERR_PARAMS:
        return "invalid parameters for the VolPack driver";
    case VPB_ERR_MEMORY:
        return "out of memory in the VolPack driver";
    case VPB_ERR_CONTEXT:
        return "vpCreateContext failed";
    default:
        if (code >= VPERROR_FIRST && code <= VPERROR_LAST)
            return vpGetErrorString((vpResult)code);
        return "unknown VolPack error";
    }
}

void vpb_destroy(VpbScene *s)
{
    if (s == NULL)
        return;
    if (s->vpc != NULL)
        vpDestroyContext(s->vpc);
    free(s->voxels);
    free(s->shade_table);
    free(s->weights);
    free(s->image);
    free(s);
}

#define CHECK(call)                                                                 \
    do {                                                                            \
        vpResult r_ = (call);                                                       \
        if (r_ != VP_OK) {                                                          \
            code = (int)r_;                                                         \
            goto fail;                                                              \
        }                                                                           \
    } while (0)

/* Creates the context, computes normals and classifies. `preprocess_ms` covers the voxel
 * array allocation, vpVolumeNormals and vpClassifyVolume. */
int vpb_create(const VpbParams *p, const unsigned char *data, VpbScene **out,
               double *preprocess_ms)
{
    VpbScene *s;
    vpContext *vpc;
    int code = 0, m, a;
    long n;
    double smin, t0;

    *out = NULL;
    if (p == NULL || data == NULL || p->materials < 1 || p->materials > VP_MAX_MATERIAL)
        return VPB_ERR_PARAMS;
    for (a = 0; a < 3; a++)
        if (p->dims[a] < 2 || p->dims[a] > VP_MAX_VOLUME_DIM || !(p->spacing[a] > 0.0))
            return VPB_ERR_PARAMS;
    n = (long)p->dims[0] * p->dims[1] * p->dims[2];

    s = calloc(1, sizeof *s);
    if (s == NULL)
        return VPB_ERR_MEMORY;
    memcpy(s->dims, p->dims, sizeof s->dims);
    smin = p->spacing[0];
    for (a = 1; a < 3; a++)
        if (p->spacing[a] < smin)
            smin = p->spacing[a];
    for (a = 0; a < 3; a++)
        s->rel_spacing[a] = p->spacing[a] / smin;
    s->pixel_offset[0] = p->pixel_offset[0];
    s->pixel_offset[1] = p->pixel_offset[1];
    for (m = 0; m < VPB_VALUES; m++)
        s->opacity[m] = p->opacity[m];
    s->materials = p->materials;
    for (m = 0; m < p->materials; m++)
        for (a = 0; a < 3; a++) {
            double v = 255.0 * (p->ka + p->kd) * p->material_rgb[3 * m + a];
            s->zero_normal[m][a] = (float)(v > 255.0 ? 255.0 : v);
        }
    s->shade_table = malloc(sizeof(float) * VPB_NORMALS * p->materials * 3);
    s->weights = malloc(sizeof(float) * VPB_VALUES * p->materials);
    if (s->shade_table == NULL || s->weights == NULL) {
        vpb_destroy(s);
        return VPB_ERR_MEMORY;
    }
    memcpy(s->weights, p->weights, sizeof(float) * VPB_VALUES * p->materials);

    vpc = s->vpc = vpCreateContext();
    if (vpc == NULL) {
        vpb_destroy(s);
        return VPB_ERR_CONTEXT;
    }
    CHECK(vpSetVolumeSize(vpc, p->dims[0], p->dims[1], p->dims[2]));
    CHECK(vpSetVoxelSize(vpc, (int)sizeof(VpbVoxel), 2, 2, 1));
    CHECK(vpSetVoxelField(vpc, FIELD_NORMAL, 2, (int)offsetof(VpbVoxel, normal),
                          VP_NORM_MAX));
    CHECK(vpSetVoxelField(vpc, FIELD_SCALAR, 1, (int)offsetof(VpbVoxel, scalar), 255));
    CHECK(vpSetClassifierTable(vpc, 0, FIELD_SCALAR, s->opacity, (int)sizeof s->opacity));
    CHECK(vpSetd(vpc, VP_MIN_VOXEL_OPACITY, p->min_opacity));
    CHECK(vpSetd(vpc, VP_MAX_RAY_OPACITY, p->max_ray_opacity));
    CHECK(vpSetLookupShader(vpc, 3, p->materials, FIELD_NORMAL, s->shade_table,
                            (int)(sizeof(float) * VPB_NORMALS * p->materials * 3),
                            FIELD_SCALAR, s->weights,
                            (int)(sizeof(float) * VPB_VALUES * p->materials)));
    for (m = 0; m < p->materials; m++) {
        const float *c = &p->material_rgb[3 * m];
        CHECK(vpSetMaterial(vpc, VP_MATERIAL0 + m, VP_AMBIENT, VP_BOTH_SIDES,
                            p->ka * c[0], p->ka * c[1], p->ka * c[2]));
        CHECK(vpSetMaterial(vpc, VP_MATERIAL0 + m, VP_DIFFUSE, VP_BOTH_SIDES,
                            p->kd * c[0], p->kd * c[1], p->kd * c[2]));
        CHECK(vpSetMaterial(vpc, VP_MATERIAL0 + m, VP_SPECULAR, VP_BOTH_SIDES, p->ks, p->ks,
                            p->ks));
        CHECK(vpSetMaterial(vpc, VP_MATERIAL0 + m, VP_SHINYNESS, VP_BOTH_SIDES,
                            p->shininess, 0.0, 0.0));
    }
    /* The model matrix is still the identity, so the direction is in camera space. */
    CHECK(vpSetLight(vpc, VP_LIGHT0, VP_DIRECTION, p->light[0], p->light[1], p->light[2]));
    CHECK(vpSetLight(vpc, VP_LIGHT0, VP_COLOR, 1.0, 1.0, 1.0));
    CHECK(vpEnable(vpc, VP_LIGHT0, 1));
    CHECK(vpEnable(vpc, VP_LIGHT_BOTH_SIDES, 1));

    t0 = now_ms();
    s->voxels = malloc(sizeof(VpbVoxel) * (size_t)n);
    if (s->voxels == NULL) {
        vpb_destroy(s);
        return VPB_ERR_MEMORY;
    }
    CHECK(vpSetRawVoxels(vpc, s->voxels, (int)(sizeof(VpbVoxel) * (size_t)n),
                         (int)sizeof(VpbVoxel), (int)sizeof(VpbVoxel) * p->dims[0],
                         (int)sizeof(VpbVoxel) * p->dims[0] * p->dims[1]));
    CHECK(vpVolumeNormals(vpc, (unsigned char *)data, (int)n, FIELD_SCALAR, VP_SKIP_FIELD,
                          FIELD_NORMAL));
    CHECK(vpClassifyVolume(vpc));
    *preprocess_ms = now_ms() - t0;
    *out = s;
    return 0;

fail:
    vpb_destroy(s);
    return code;
}

/* Bytes of the three run-length encoded copies. */
long vpb_classified_bytes(const VpbScene *s)
{
    int x = 0, y = 0, z = 0;
    vpGeti(s->vpc, VP_VIEW_X_SIZE, &x);
    vpGeti(s->vpc, VP_VIEW_Y_SIZE, &y);
    vpGeti(s->vpc, VP_VIEW_Z_SIZE, &z);
    return (long)x + y + z;
}

/* Sine and cosine of an angle in degrees, exact at multiples of 90 degrees (as in
 * shearwarp's core, so axis-aligned views are exactly axis-aligned in both). */
static void sincos_deg(double deg, double *s, double *c)
{
    double r = fmod(deg, 360.0);
    if (r < 0.0)
        r += 360.0;
    if (r == 0.0) {
        *s = 0.0;
        *c = 1.0;
    } else if (r == 90.0) {
        *s = 1.0;
        *c = 0.0;
    } else if (r == 180.0) {
        *s = 0.0;
        *c = -1.0;
    } else if (r == 270.0) {
        *s = -1.0;
        *c = 0.0;
    } else {
        double rad = r * (VPB_PI / 180.0);
        *s = sin(rad);
        *c = cos(rad);
    }
}

/* shearwarp's object-to-camera rotation R = Rx(rx) * Ry(ry), right-handed. (vpRotate
 * builds the transpose of the usual counter-clockwise matrix, so the matrix is set
 * directly instead.) */
static void rotation(double rx, double ry, double r[3][3])
{
    double sx, cx, sy, cy;
    sincos_deg(rx, &sx, &cx);
    sincos_deg(ry, &sy, &cy);
    r[0][0] = cy;
    r[0][1] = 0.0;
    r[0][2] = sy;
    r[1][0] = sx * sy;
    r[1][1] = cx;
    r[1][2] = -sx * cy;
    r[2][0] = -cx * sy;
    r[2][1] = sx;
    r[2][2] = cx * cy;
}

/* Renders one frame into `rgb` (width * height * 3 bytes, row 0 at the top). `render_ms`
 * covers the view setup, vpShadeTable and vpRenderClassifiedVolume (which includes the
 * warp into the final image). */
int vpb_render(VpbScene *s, double rx, double ry, int width, int height, unsigned char *rgb,
               double *render_ms)
{
    vpContext *vpc = s->vpc;
    vpMatrix4 model;
    int code = 0, maxdim, a, b, row;
    double diag2 = 0.0, half, hx, hy, h, t0, off[3], rot[3][3];

    if (width < 1 || height < 1)
        return VPB_ERR_PARAMS;
    if (width != s->width || height != s->height) {
        unsigned char *img = realloc(s->image, (size_t)width * height * 3);
        if (img == NULL)
            return VPB_ERR_MEMORY;
        s->image = img;
        s->width = width;
        s->height = height;
        CHECK(vpSetImage(vpc, s->image, width, height, width * 3, VP_RGB));
    }
    maxdim = s->dims[0];
    for (a = 1; a < 3; a++)
        if (s->dims[a] > maxdim)
            maxdim = s->dims[a];
    for (a = 0; a < 3; a++) {
        double e = s->dims[a] * s->rel_spacing[a];
        diag2 += e * e;
    }
    /* Half the diagonal in VolPack's world units (1 = maxdim voxels of the smallest
     * spacing); it spans half the shorter image side. */
    half = 0.5 * sqrt(diag2) / maxdim;
    hx = half * (width > height ? (double)width / height : 1.0);
    hy = half * (height > width ? (double)height / width : 1.0);

    rotation(rx, ry, rot);
    vpIdentity4(model);
    for (a = 0; a < 3; a++)
        for (b = 0; b < 3; b++)
            model[a][b] = rot[a][b] * s->rel_spacing[b];
    /* Half a voxel along each object axis, carried into camera space by MODEL, plus the
     * optional image-space calibration shift (world units per pixel: 2*hx/width). */
    h = 0.5 / maxdim;
    for (a = 0; a < 3; a++)
        off[a] = (model[a][0] + model[a][1] + model[a][2]) * h;
    off[0] += s->pixel_offset[0] * 2.0 * hx / width;
    off[1] -= s->pixel_offset[1] * 2.0 * hy / height;

    t0 = now_ms();
    CHECK(vpCurrentMatrix(vpc, VP_MODEL));
    CHECK(vpSetMatrix(vpc, model));
    /* VolPack composites as seen from -z of its eye space (its viewport flips z to a
     * left-handed frame) but shades for a viewer at +z of world space. With MODEL the
     * object-to-camera rotation, world space is shearwarp's camera space, so the shading
     * is right as is; VIEW mirrors z so that the compositing sees the volume from +z. */
    CHECK(vpCurrentMatrix(vpc, VP_VIEW));
    CHECK(vpIdentityMatrix(vpc));
    CHECK(vpScale(vpc, 1.0, 1.0, -1.0));
    CHECK(vpTranslate(vpc, off[0], off[1], off[2]));
    CHECK(vpCurrentMatrix(vpc, VP_PROJECT));
    CHECK(vpIdentityMatrix(vpc));
    CHECK(vpWindow(vpc, VP_PARALLEL, -hx, hx, -hy, hy, -half, half));
    CHECK(vpShadeTable(vpc));
    /* Normal codes 0 and 1 are VolPack's zero gradient (flat regions and the volume's
     * faces), which vpShadeTable shades with the ambient term only; shearwarp and the
     * reference give such voxels ambient plus full diffuse light, so patch those rows. */
    for (a = 0; a < 2; a++)
        for (b = 0; b < s->materials; b++)
            memcpy(&s->shade_table[(a * s->materials + b) * 3], s->zero_normal[b],
                   sizeof s->zero_normal[b]);
    CHECK(vpRenderClassifiedVolume(vpc));
    *render_ms = now_ms() - t0;

    /* VolPack's image row 0 is at the bottom (y up); return it top row first. */
    for (row = 0; row < height; row++)
        memcpy(rgb + (size_t)row * width * 3,
               s->image + (size_t)(height - 1 - row) * width * 3, (size_t)width * 3);
    return 0;

fail:
    return code;
}
