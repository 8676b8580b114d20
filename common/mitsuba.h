/* mitsuba.h - Mitsuba 3 scene files (XML), read into vbrender's own scene
 * model: the scene JSON of docs/SCENES.md, which every later stage (the
 * client's bundle, the master's checks, the workers' loader) already takes.
 *
 * The XML is parsed by libexpat. What the file system holds (includes,
 * meshes) is read here, on the submitting side; the JSON names every mesh
 * by its resolved path, so the job bundle carries it as it carries the
 * meshes of a JSON scene, and no worker needs the scene's folder.
 *
 * The subset is what the scenes we render use, and grows scene by scene
 * (docs/SCENES.md lists it). Anything outside it is refused with the file,
 * the line and the plugin or property it cannot honour, never drawn
 * differently. */
#ifndef VB_MITSUBA_H
#define VB_MITSUBA_H

#include <stddef.h>

#include <cJSON.h>

#include "scene.h"

/* Reads the Mitsuba scene `path`. defines holds define_count "name=value"
 * strings, Mitsuba's -D: they override the file's <default> values.
 * Returns a new scene JSON object (free with cJSON_Delete), or NULL with
 * "FILE:LINE: what is wrong" in err. */
cJSON *mitsuba_scene_json(const char *path, const char *const *defines, size_t define_count,
                          char *err, size_t errlen);

/* 1 when path names a Mitsuba scene (ends in ".xml", any case). */
int mitsuba_is_scene_path(const char *path);

/* Loads path as scene_load does, a Mitsuba scene (mitsuba_is_scene_path)
 * through the JSON it becomes, its files found beside it: for tools that
 * trace a scene file of either kind (bench_core, bench_batches). Returns 0
 * and *out, or -1 with a message in err. */
int mitsuba_scene_load(const char *path, scene_t **out, char *err, size_t errlen);

/* A wavelength:value spectrum (nm, ascending) as Mitsuba 3's RGB variants
 * turn it into linear sRGB: the piecewise linear spectrum, zero outside
 * its first and last wavelength, integrated against the CIE 1931 2-degree
 * colour matching functions; for a reflectance (reflectance != 0) under
 * the D65 illuminant and clamped to [0, 1], for a radiance as it is and
 * clamped below at 0. Returns -1 when fewer than 2 wavelengths are given
 * or they do not ascend. */
int mitsuba_spectrum_rgb(const double *nm, const double *values, size_t count, int reflectance,
                         double rgb[3]);

#endif
