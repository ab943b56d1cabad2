/* A first-order thermal model as an FMI 2.0 FMU (model exchange and co-simulation).
 *
 *   dT/dt = (K * u - (T - T_amb)) / tau,   T(0) = T_amb
 *
 * Co-simulation integrates one communication step exactly for the input held at the
 * step's start. A positive fail_time makes every call at or after that time fail
 * (fmi2Error), so tests can check how a simulation failing mid-segment is reported.
 * Built by tests/datasets/test_fmu.py with the FMI headers that fmpy ships.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "fmi2Functions.h"

enum { VR_T, VR_DER_T, VR_U, VR_K, VR_TAU, VR_T_AMB, VR_FAIL_TIME, N_VR };

typedef struct {
    fmi2Real v[N_VR];
    fmi2Real time;
    const fmi2CallbackFunctions *cb;
    fmi2String name;
} Thermal;

static void defaults(Thermal *m) {
    memset(m->v, 0, sizeof(m->v));
    m->v[VR_K] = 1.0;
    m->v[VR_TAU] = 10.0;
    m->v[VR_T_AMB] = 20.0;
    m->v[VR_FAIL_TIME] = -1.0;
    m->v[VR_T] = m->v[VR_T_AMB];
    m->time = 0.0;
}

static int failing(Thermal *m, fmi2Real t) {
    if (m->v[VR_FAIL_TIME] > 0.0 && t >= m->v[VR_FAIL_TIME]) {
        if (m->cb && m->cb->logger)
            m->cb->logger(m->cb->componentEnvironment, m->name, fmi2Error, "error", "thermal: failure injected");
        return 1;
    }
    return 0;
}

static fmi2Real derivative(const Thermal *m) {
    return (m->v[VR_K] * m->v[VR_U] - (m->v[VR_T] - m->v[VR_T_AMB])) / m->v[VR_TAU];
}

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }
fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cat[]) { return fmi2OK; }

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String resources,
                              const fmi2CallbackFunctions *cb, fmi2Boolean visible, fmi2Boolean logging) {
    Thermal *m = (Thermal *)calloc(1, sizeof(Thermal));
    if (!m) return NULL;
    defaults(m);
    m->cb = cb;
    m->name = name;
    return m;
}

void fmi2FreeInstance(fmi2Component c) { free(c); }

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tolDefined, fmi2Real tol, fmi2Real start,
                               fmi2Boolean stopDefined, fmi2Real stop) {
    ((Thermal *)c)->time = start;
    return fmi2OK;
}
fmi2Status fmi2EnterInitializationMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    Thermal *m = (Thermal *)c;
    if (!(m->v[VR_TAU] > 0.0)) return fmi2Error;
    m->v[VR_T] = m->v[VR_T_AMB];
    return fmi2OK;
}
fmi2Status fmi2Terminate(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2Reset(fmi2Component c) { defaults((Thermal *)c); return fmi2OK; }

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real value[]) {
    Thermal *m = (Thermal *)c;
    for (size_t i = 0; i < n; i++) {
        if (vr[i] >= N_VR) return fmi2Error;
        value[i] = vr[i] == VR_DER_T ? derivative(m) : m->v[vr[i]];
    }
    return fmi2OK;
}
fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real value[]) {
    Thermal *m = (Thermal *)c;
    for (size_t i = 0; i < n; i++) {
        if (vr[i] >= N_VR || vr[i] == VR_DER_T) return fmi2Error;
        m->v[vr[i]] = value[i];
    }
    return fmi2OK;
}
fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[]) { return n ? fmi2Error : fmi2OK; }
fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[]) { return n ? fmi2Error : fmi2OK; }
fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[]) { return n ? fmi2Error : fmi2OK; }
fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer v[]) { return n ? fmi2Error : fmi2OK; }
fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[]) { return n ? fmi2Error : fmi2OK; }
fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String v[]) { return n ? fmi2Error : fmi2OK; }

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s) { return fmi2Error; }
fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s) { return fmi2Error; }
fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s) { return fmi2Error; }
fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *n) { return fmi2Error; }
fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t n) { return fmi2Error; }
fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t n, fmi2FMUstate *s) { return fmi2Error; }
fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference k[], size_t nk, const fmi2Real dk[], fmi2Real du[]) {
    return fmi2Error;
}

/* model exchange */
fmi2Status fmi2EnterEventMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *e) {
    memset(e, 0, sizeof(*e));
    return fmi2OK;
}
fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) { return fmi2OK; }
fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noPrior, fmi2Boolean *event, fmi2Boolean *stop) {
    *event = fmi2False;
    *stop = fmi2False;
    return fmi2OK;
}
fmi2Status fmi2SetTime(fmi2Component c, fmi2Real t) { ((Thermal *)c)->time = t; return fmi2OK; }
fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    ((Thermal *)c)->v[VR_T] = x[0];
    return fmi2OK;
}
fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real dx[], size_t nx) {
    Thermal *m = (Thermal *)c;
    if (failing(m, m->time)) return fmi2Error;
    dx[0] = derivative(m);
    return fmi2OK;
}
fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real z[], size_t nz) { return fmi2OK; }
fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    x[0] = ((Thermal *)c)->v[VR_T];
    return fmi2OK;
}
fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    x[0] = 1.0;
    return fmi2OK;
}

/* co-simulation */
fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                       const fmi2Integer order[], const fmi2Real v[]) { return fmi2Error; }
fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                        const fmi2Integer order[], fmi2Real v[]) { return fmi2Error; }
fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noPrior) {
    Thermal *m = (Thermal *)c;
    if (failing(m, t + h)) return fmi2Error;
    fmi2Real steady = m->v[VR_T_AMB] + m->v[VR_K] * m->v[VR_U];
    m->v[VR_T] = steady + (m->v[VR_T] - steady) * exp(-h / m->v[VR_TAU]);
    m->time = t + h;
    return fmi2OK;
}
fmi2Status fmi2CancelStep(fmi2Component c) { return fmi2Error; }
fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *v) { return fmi2Error; }
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *v) { return fmi2Error; }
fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *v) { return fmi2Error; }
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *v) { return fmi2Error; }
fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *v) { return fmi2Error; }
