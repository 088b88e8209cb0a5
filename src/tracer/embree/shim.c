/* Embree's rtcInit* helpers are `static inline` in the headers (no symbol in libembree4): export them
   so the Rust side runs exactly the installed headers' initialisation. */
#include <embree4/rtcore.h>

void diffcassi_rtcInitRayQueryContext(struct RTCRayQueryContext* context) { rtcInitRayQueryContext(context); }
void diffcassi_rtcInitIntersectArguments(struct RTCIntersectArguments* args) { rtcInitIntersectArguments(args); }
