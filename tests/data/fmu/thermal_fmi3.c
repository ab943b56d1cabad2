/* The first-order thermal model of thermal_fmi2.c as an FMI 3.0 FMU (model exchange and co-simulation).
 *
 *   dT/dt = (K * u - (T - T_amb)) / tau,   T(0) = T_amb
 *
 * Self-contained (no FMI headers): the FMI 3.0 types are plain C types (fmi3Float64 =
 * double, fmi3Boolean = bool, fmi3ValueReference = uint32_t, fmi3Status = int). Functions
 * the model does not use are stubs answering fmi3Error, there only because fmpy binds
 * every FMI 3.0 function when it loads the library.
 */
#include <math.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>

#define OK 0
#define ERROR 3
#define EXPORT __attribute__((visibility("default")))

enum { VR_T, VR_DER_T, VR_U, VR_K, VR_TAU, VR_T_AMB, VR_FAIL_TIME, VR_TIME, N_VR };

typedef void (*LogMessage)(void *env, int status, const char *category, const char *message);

typedef struct {
    double v[N_VR];
    void *env;
    LogMessage log;
} Thermal;

static void defaults(Thermal *m) {
    for (int i = 0; i < N_VR; i++) m->v[i] = 0.0;
    m->v[VR_K] = 1.0;
    m->v[VR_TAU] = 10.0;
    m->v[VR_T_AMB] = 20.0;
    m->v[VR_FAIL_TIME] = -1.0;
    m->v[VR_T] = m->v[VR_T_AMB];
}

static int failing(Thermal *m, double t) {
    if (m->v[VR_FAIL_TIME] > 0.0 && t >= m->v[VR_FAIL_TIME]) {
        if (m->log) m->log(m->env, ERROR, "logStatusError", "thermal: failure injected");
        return 1;
    }
    return 0;
}

static double derivative(const Thermal *m) {
    return (m->v[VR_K] * m->v[VR_U] - (m->v[VR_T] - m->v[VR_T_AMB])) / m->v[VR_TAU];
}

static void *create(void *env, LogMessage log) {
    Thermal *m = (Thermal *)calloc(1, sizeof(Thermal));
    if (!m) return NULL;
    defaults(m);
    m->env = env;
    m->log = log;
    return m;
}

EXPORT const char *fmi3GetVersion(void) { return "3.0"; }
EXPORT int fmi3SetDebugLogging(void *c, bool on, size_t n, const char *const cat[]) { return OK; }

EXPORT void *fmi3InstantiateModelExchange(const char *name, const char *token, const char *resources, bool visible,
                                          bool logging, void *env, LogMessage log) {
    return create(env, log);
}
EXPORT void *fmi3InstantiateCoSimulation(const char *name, const char *token, const char *resources, bool visible,
                                         bool logging, bool eventMode, bool earlyReturn, const uint32_t req[],
                                         size_t nreq, void *env, LogMessage log, void *update) {
    return create(env, log);
}
EXPORT void fmi3FreeInstance(void *c) { free(c); }

EXPORT int fmi3EnterInitializationMode(void *c, bool tolDefined, double tol, double start, bool stopDefined,
                                       double stop) {
    ((Thermal *)c)->v[VR_TIME] = start;
    return OK;
}
EXPORT int fmi3ExitInitializationMode(void *c) {
    Thermal *m = (Thermal *)c;
    if (!(m->v[VR_TAU] > 0.0)) return ERROR;
    m->v[VR_T] = m->v[VR_T_AMB];
    return OK;
}
EXPORT int fmi3Terminate(void *c) { return OK; }
EXPORT int fmi3Reset(void *c) { defaults((Thermal *)c); return OK; }

EXPORT int fmi3GetFloat64(void *c, const uint32_t vr[], size_t n, double value[], size_t nv) {
    Thermal *m = (Thermal *)c;
    for (size_t i = 0; i < n; i++) {
        if (vr[i] >= N_VR) return ERROR;
        value[i] = vr[i] == VR_DER_T ? derivative(m) : m->v[vr[i]];
    }
    return OK;
}
EXPORT int fmi3SetFloat64(void *c, const uint32_t vr[], size_t n, const double value[], size_t nv) {
    Thermal *m = (Thermal *)c;
    for (size_t i = 0; i < n; i++) {
        if (vr[i] >= N_VR || vr[i] == VR_DER_T || vr[i] == VR_TIME) return ERROR;
        m->v[vr[i]] = value[i];
    }
    return OK;
}

/* model exchange */
EXPORT int fmi3EnterEventMode(void *c) { return OK; }
EXPORT int fmi3UpdateDiscreteStates(void *c, bool *update, bool *stop, bool *nominals, bool *values, bool *timeDefined,
                                    double *next) {
    *update = *stop = *nominals = *values = *timeDefined = false;
    *next = 0.0;
    return OK;
}
EXPORT int fmi3EnterContinuousTimeMode(void *c) { return OK; }
EXPORT int fmi3CompletedIntegratorStep(void *c, bool noPrior, bool *event, bool *stop) {
    *event = *stop = false;
    return OK;
}
EXPORT int fmi3SetTime(void *c, double t) { ((Thermal *)c)->v[VR_TIME] = t; return OK; }
EXPORT int fmi3SetContinuousStates(void *c, const double x[], size_t nx) { ((Thermal *)c)->v[VR_T] = x[0]; return OK; }
EXPORT int fmi3GetContinuousStateDerivatives(void *c, double dx[], size_t nx) {
    Thermal *m = (Thermal *)c;
    if (failing(m, m->v[VR_TIME])) return ERROR;
    dx[0] = derivative(m);
    return OK;
}
EXPORT int fmi3GetEventIndicators(void *c, double z[], size_t nz) { return OK; }
EXPORT int fmi3GetContinuousStates(void *c, double x[], size_t nx) { x[0] = ((Thermal *)c)->v[VR_T]; return OK; }
EXPORT int fmi3GetNominalsOfContinuousStates(void *c, double x[], size_t nx) { x[0] = 1.0; return OK; }
EXPORT int fmi3GetNumberOfEventIndicators(void *c, size_t *n) { *n = 0; return OK; }
EXPORT int fmi3GetNumberOfContinuousStates(void *c, size_t *n) { *n = 1; return OK; }

/* co-simulation: one communication step integrated exactly for the input held at its start */
EXPORT int fmi3EnterStepMode(void *c) { return OK; }
EXPORT int fmi3DoStep(void *c, double t, double h, bool noPrior, bool *eventNeeded, bool *stop, bool *early,
                      double *last) {
    Thermal *m = (Thermal *)c;
    *eventNeeded = *stop = *early = false;
    *last = t;
    if (failing(m, t + h)) return ERROR;
    double steady = m->v[VR_T_AMB] + m->v[VR_K] * m->v[VR_U];
    m->v[VR_T] = steady + (m->v[VR_T] - steady) * exp(-h / m->v[VR_TAU]);
    m->v[VR_TIME] = *last = t + h;
    return OK;
}

/* not used by this model */
#define STUB(name) EXPORT int name(void) { return ERROR; }
STUB(fmi3ActivateModelPartition) STUB(fmi3DeserializeFMUState) STUB(fmi3EnterConfigurationMode)
STUB(fmi3EvaluateDiscreteStates) STUB(fmi3ExitConfigurationMode) STUB(fmi3FreeFMUState)
STUB(fmi3GetAdjointDerivative) STUB(fmi3GetBinary) STUB(fmi3GetBoolean) STUB(fmi3GetClock)
STUB(fmi3GetDirectionalDerivative) STUB(fmi3GetFMUState) STUB(fmi3GetFloat32) STUB(fmi3GetInt16)
STUB(fmi3GetInt32) STUB(fmi3GetInt64) STUB(fmi3GetInt8) STUB(fmi3GetIntervalDecimal) STUB(fmi3GetIntervalFraction)
STUB(fmi3GetNumberOfVariableDependencies) STUB(fmi3GetOutputDerivatives) STUB(fmi3GetShiftDecimal)
STUB(fmi3GetShiftFraction) STUB(fmi3GetString) STUB(fmi3GetUInt16) STUB(fmi3GetUInt32) STUB(fmi3GetUInt64)
STUB(fmi3GetUInt8) STUB(fmi3GetVariableDependencies) STUB(fmi3InstantiateScheduledExecution)
STUB(fmi3SerializeFMUState) STUB(fmi3SerializedFMUStateSize) STUB(fmi3SetBinary) STUB(fmi3SetBoolean)
STUB(fmi3SetClock) STUB(fmi3SetFMUState) STUB(fmi3SetFloat32) STUB(fmi3SetInt16) STUB(fmi3SetInt32)
STUB(fmi3SetInt64) STUB(fmi3SetInt8) STUB(fmi3SetIntervalDecimal) STUB(fmi3SetIntervalFraction)
STUB(fmi3SetShiftDecimal) STUB(fmi3SetShiftFraction) STUB(fmi3SetString) STUB(fmi3SetUInt16) STUB(fmi3SetUInt32)
STUB(fmi3SetUInt64) STUB(fmi3SetUInt8)
