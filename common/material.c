/* material.c - material names; the BSDFs themselves are inline in
 * material.h because they sit on the tracer's hot path. */
#include "material.h"

#include <string.h>

static const char *const type_names[] = {"diffuse", "emitter", "mirror", "dielectric"};

int material_type_from_name(const char *name)
{
    for (int i = 0; i < (int)(sizeof type_names / sizeof type_names[0]); i++)
        if (strcmp(name, type_names[i]) == 0)
            return i;
    return -1;
}

const char *material_type_name(material_type_t type)
{
    return (unsigned)type < sizeof type_names / sizeof type_names[0] ? type_names[type] : "?";
}
