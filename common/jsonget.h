/* jsonget.h - reading a field of a JSON reply that may be missing: a number
 * (0 when absent or not a number) or a string ("" likewise). For readers of
 * the control protocol's replies, whose fields grow over versions. */
#ifndef VB_JSONGET_H
#define VB_JSONGET_H

#include <cJSON.h>

static inline double json_num(const cJSON *o, const char *key)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(o, key);
    return cJSON_IsNumber(v) ? v->valuedouble : 0.0;
}

static inline const char *json_str(const cJSON *o, const char *key)
{
    const cJSON *v = cJSON_GetObjectItemCaseSensitive(o, key);
    return cJSON_IsString(v) ? v->valuestring : "";
}

#endif
