"""An FMI 2.0 co-simulation FMU around a ``CModel``'s step core, compiled here with gcc (linux64 binary + C source).

The FMU's variables: one Real input per model input, one Real output per target, one Real input
``<target>_measured`` per target (read during the init window only), the Integer parameter
``init_samples`` (the init window, at least 1: the run's ``init_samples``) and the Boolean output
``diverged``. Its step is the data's sample period ``dt`` (``DefaultExperiment stepSize``); ``doStep``
accepts whole multiples of it (inputs held) and refuses any other step size.

Outputs have direct feedthrough where the model reads u(t) (nk = 0): a master sets the inputs of
t_i, reads the outputs of t_i, then calls ``doStep(t_i, dt)`` (``simulate_fmu`` in ``verify``).
fmpy's ``simulate_fmu`` samples outputs after ``doStep`` and before the next inputs are set, so
with a feedthrough its recorded outputs of t_i+1 still see the inputs of t_i.

The FMI 2.0 types and function names are declared here from the standard's text (no header copied).
"""

from __future__ import annotations

import hashlib
import json
import tempfile
import time
import zipfile
from pathlib import Path
from typing import Any
from xml.sax.saxutils import quoteattr

import numpy as np

from enginebench.errors import MethodError
from enginebench.c_model import CModel, c_double, c_source
from enginebench.methods.export.harness import compile_shared

FMI2 = r"""
/* FMI 2.0 co-simulation interface (types and functions as the FMI 2.0 standard defines them) */
#include <stdlib.h>
#include <stdio.h>
typedef void *fmi2Component;
typedef void *fmi2ComponentEnvironment;
typedef void *fmi2FMUstate;
typedef unsigned int fmi2ValueReference;
typedef double fmi2Real;
typedef int fmi2Integer;
typedef int fmi2Boolean;
typedef char fmi2Char;
typedef const fmi2Char *fmi2String;
typedef char fmi2Byte;
typedef enum { fmi2OK, fmi2Warning, fmi2Discard, fmi2Error, fmi2Fatal, fmi2Pending } fmi2Status;
typedef enum { fmi2ModelExchange, fmi2CoSimulation } fmi2Type;
typedef enum { fmi2DoStepStatus, fmi2PendingStatus, fmi2LastSuccessfulTime, fmi2Terminated } fmi2StatusKind;
typedef void (*fmi2CallbackLogger)(fmi2ComponentEnvironment, fmi2String, fmi2Status, fmi2String, fmi2String, ...);
typedef struct {
    fmi2CallbackLogger logger;
    void *(*allocateMemory)(size_t, size_t);
    void (*freeMemory)(void *);
    void (*stepFinished)(fmi2ComponentEnvironment, fmi2Status);
    fmi2ComponentEnvironment componentEnvironment;
} fmi2CallbackFunctions;
#define EXPORT __attribute__((visibility("default")))

typedef struct {
    eb_model m;
    double u[NU + 1];
    double ymeas[NY + 1];
    long init;
    double time;
    fmi2CallbackLogger logger;
    fmi2ComponentEnvironment env;
    char name[128];
} eb_instance;

static void eb_log(eb_instance *c, fmi2Status status, const char *message) {
    if (c && c->logger) c->logger(c->env, c->name, status, status == fmi2OK ? "logAll" : "logStatusError", "%s", message);
}

EXPORT const char *fmi2GetTypesPlatform(void) { return "default"; }
EXPORT const char *fmi2GetVersion(void) { return "2.0"; }
EXPORT fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cats[]) { return fmi2OK; }

EXPORT fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String location,
                                     const fmi2CallbackFunctions *functions, fmi2Boolean visible, fmi2Boolean logging) {
    if (type != fmi2CoSimulation || guid == NULL || strcmp(guid, EB_GUID) != 0) {
        if (functions && functions->logger)
            functions->logger(functions->componentEnvironment, name, fmi2Error, "logStatusError",
                              "%s", "this FMU is co-simulation only, with GUID " EB_GUID);
        return NULL;
    }
    eb_instance *c = (eb_instance *)calloc(1, sizeof(eb_instance));
    if (!c) return NULL;
    c->init = EB_INIT;
    if (functions) { c->logger = functions->logger; c->env = functions->componentEnvironment; }
    snprintf(c->name, sizeof(c->name), "%s", name ? name : "");
    eb_reset(&c->m, c->init);
    return c;
}

EXPORT void fmi2FreeInstance(fmi2Component c) { free(c); }
EXPORT fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tolDefined, fmi2Real tol, fmi2Real start,
                                      fmi2Boolean stopDefined, fmi2Real stop) {
    ((eb_instance *)c)->time = start;
    return fmi2OK;
}
EXPORT fmi2Status fmi2EnterInitializationMode(fmi2Component c) { return fmi2OK; }
EXPORT fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    eb_instance *e = (eb_instance *)c;
    eb_reset(&e->m, e->init);
    return fmi2OK;
}
EXPORT fmi2Status fmi2Terminate(fmi2Component c) { return fmi2OK; }
EXPORT fmi2Status fmi2Reset(fmi2Component c) {
    eb_instance *e = (eb_instance *)c;
    e->init = EB_INIT;
    eb_reset(&e->m, e->init);
    return fmi2OK;
}

EXPORT fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real value[]) {
    eb_instance *e = (eb_instance *)c;
    eb_set_inputs(&e->m, e->u);
    const double *y = eb_outputs(&e->m, e->ymeas);
    for (size_t i = 0; i < n; i++) {
        unsigned int r = vr[i];
        if (r < NU) value[i] = e->u[r];
        else if (r < NU + NY) value[i] = y[r - NU];
        else if (r < NU + 2 * NY) value[i] = e->ymeas[r - NU - NY];
        else { eb_log(e, fmi2Error, "fmi2GetReal: unknown value reference"); return fmi2Error; }
    }
    return fmi2OK;
}
EXPORT fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real value[]) {
    eb_instance *e = (eb_instance *)c;
    for (size_t i = 0; i < n; i++) {
        unsigned int r = vr[i];
        if (r < NU) e->u[r] = value[i];
        else if (r >= NU + NY && r < NU + 2 * NY) e->ymeas[r - NU - NY] = value[i];
        else { eb_log(e, fmi2Error, "fmi2SetReal: only inputs can be set"); return fmi2Error; }
    }
    return fmi2OK;
}
EXPORT fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer value[]) {
    for (size_t i = 0; i < n; i++) { if (vr[i] != 0) return fmi2Error; value[i] = (fmi2Integer)((eb_instance *)c)->init; }
    return fmi2OK;
}
EXPORT fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer value[]) {
    eb_instance *e = (eb_instance *)c;
    for (size_t i = 0; i < n; i++) {
        if (vr[i] != 0 || value[i] < 1) { eb_log(e, fmi2Error, "init_samples must be >= 1"); return fmi2Error; }
        e->init = value[i];
    }
    return fmi2OK;
}
EXPORT fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean value[]) {
    eb_instance *e = (eb_instance *)c;
    eb_set_inputs(&e->m, e->u);
    eb_outputs(&e->m, e->ymeas);
    for (size_t i = 0; i < n; i++) { if (vr[i] != 0) return fmi2Error; value[i] = e->m.diverged; }
    return fmi2OK;
}
EXPORT fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[]) { return n ? fmi2Error : fmi2OK; }
EXPORT fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[]) { return n ? fmi2Error : fmi2OK; }
EXPORT fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String v[]) { return n ? fmi2Error : fmi2OK; }
EXPORT fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s) { return fmi2Error; }
EXPORT fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s) { return fmi2Error; }
EXPORT fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s) { return fmi2Error; }
EXPORT fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *n) { return fmi2Error; }
EXPORT fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t n) { return fmi2Error; }
EXPORT fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t n, fmi2FMUstate *s) { return fmi2Error; }
EXPORT fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference a[], size_t na,
                                               const fmi2ValueReference b[], size_t nb, const fmi2Real dv[], fmi2Real r[]) { return fmi2Error; }
EXPORT fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                              const fmi2Integer order[], const fmi2Real value[]) { return fmi2Error; }
EXPORT fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                               const fmi2Integer order[], fmi2Real value[]) { return fmi2Error; }

EXPORT fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior) {
    eb_instance *e = (eb_instance *)c;
    double k = floor(h / EB_DT + 0.5);
    if (k < 1 || fabs(k * EB_DT - h) > 1e-9 * EB_DT * k) {
        eb_log(e, fmi2Error, "fmi2DoStep: the step size must be a whole multiple of the model's sample period");
        return fmi2Error;
    }
    for (long s = 0; s < (long)k; s++) { eb_set_inputs(&e->m, e->u); eb_commit(&e->m, e->ymeas); }
    e->time = t + h;
    return fmi2OK;
}
EXPORT fmi2Status fmi2CancelStep(fmi2Component c) { return fmi2Error; }
EXPORT fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *v) { return fmi2Discard; }
EXPORT fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *v) {
    if (s != fmi2LastSuccessfulTime) return fmi2Discard;
    *v = ((eb_instance *)c)->time;
    return fmi2OK;
}
EXPORT fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *v) { return fmi2Discard; }
EXPORT fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *v) {
    if (s != fmi2Terminated) return fmi2Discard;
    *v = 0;
    return fmi2OK;
}
EXPORT fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *v) { return fmi2Discard; }
"""


def identifier(model: CModel, source: str) -> str:
    """The FMU's model identifier: a C name from the method and a digest of the source."""
    stem = "".join(ch if ch.isalnum() else "_" for ch in model.method)
    return f"eb_{stem}_{hashlib.sha256(source.encode()).hexdigest()[:10]}"


def model_description(model: CModel, ident: str, guid: str, dt: float, init: int, stop: float, about: str,
                      units: dict[str, str]) -> str:
    def var(name: str, vr: int, causality: str, variability: str, kind: str, extra: str = "", start: str = "",
            initial: str = "") -> str:
        attrs = f"name={quoteattr(name)} valueReference=\"{vr}\" causality=\"{causality}\" variability=\"{variability}\""
        attrs += f" initial=\"{initial}\"" if initial else ""
        unit = f" unit={quoteattr(units[name])}" if kind == "Real" and units.get(name) else ""
        inner = f"<{kind}{unit}{f' start={quoteattr(start)}' if start else ''}{extra}/>"
        return f"    <ScalarVariable {attrs}>{inner}</ScalarVariable>"

    nu, ny = len(model.inputs), len(model.targets)
    rows = [var(u, i, "input", "continuous", "Real", start="0.0") for i, u in enumerate(model.inputs)]
    rows += [var(y, nu + j, "output", "discrete", "Real", initial="calculated") for j, y in enumerate(model.targets)]
    rows += [var(f"{y}_measured", nu + ny + j, "input", "discrete", "Real", start="0.0")
             for j, y in enumerate(model.targets)]
    rows.append(var("init_samples", 0, "parameter", "fixed", "Integer", start=str(init)))
    rows.append(var("diverged", 0, "output", "discrete", "Boolean", initial="calculated"))
    outputs = [nu + j + 1 for j in range(ny)] + [nu + 2 * ny + 2]
    unknowns = "\n".join(f"      <Unknown index=\"{i}\"/>" for i in outputs)
    used = sorted({u for u in units.values() if u})
    unit_defs = ("  <UnitDefinitions>\n" + "\n".join(f"    <Unit name={quoteattr(u)}/>" for u in used)
                 + "\n  </UnitDefinitions>\n") if used else ""
    stamp = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<fmiModelDescription fmiVersion="2.0" modelName={quoteattr(ident)} guid={quoteattr(guid)}
  description={quoteattr(about)} generationTool="enginebench" generationDateAndTime="{stamp}"
  variableNamingConvention="flat" numberOfEventIndicators="0">
  <CoSimulation modelIdentifier="{ident}" canHandleVariableCommunicationStepSize="false"
    canBeInstantiatedOnlyOncePerProcess="false" canNotUseMemoryManagementFunctions="true"
    canGetAndSetFMUstate="false" canSerializeFMUstate="false" providesDirectionalDerivative="false">
    <SourceFiles><File name="{ident}.c"/></SourceFiles>
  </CoSimulation>
{unit_defs}  <DefaultExperiment startTime="0.0" stopTime="{c_double(stop)}" stepSize="{c_double(dt)}"/>
  <ModelVariables>
{chr(10).join(rows)}
  </ModelVariables>
  <ModelStructure>
    <Outputs>
{unknowns}
    </Outputs>
    <InitialUnknowns>
{unknowns}
    </InitialUnknowns>
  </ModelStructure>
</fmiModelDescription>
"""


def fmu_source(model: CModel, guid: str, dt: float, init: int) -> str:
    return (c_source(model) + f"\n#define EB_GUID {json.dumps(guid)}\n#define EB_DT {c_double(dt)}\n"
            f"#define EB_INIT {max(int(init), 1)}\n" + FMI2)


def build_fmu(model: CModel, out: str | Path, *, dt: float, init: int, stop: float, about: str,
              resources: dict[str, Any], units: dict[str, str] | None = None) -> Path:
    """Write the FMU ``out``: model description, linux64 binary (gcc), C source and ``resources/enginebench.json``."""
    if not np.isfinite(dt) or dt <= 0:
        raise MethodError(f"cannot export: the data's sample period {dt!r} is not a positive number of seconds")
    out = Path(out)
    probe = fmu_source(model, "{00000000-0000-0000-0000-000000000000}", dt, init)
    ident = identifier(model, probe)
    guid = "{" + str(hashlib.sha256(probe.encode()).hexdigest()[:32]) + "}"
    guid = f"{{{guid[1:9]}-{guid[9:13]}-{guid[13:17]}-{guid[17:21]}-{guid[21:33]}}}"
    source = fmu_source(model, guid, dt, init)
    with tempfile.TemporaryDirectory(prefix="enginebench-fmu-") as tmp:
        lib = compile_shared(source, Path(tmp) / f"{ident}.so", f"export of method {model.method!r}")
        xml = model_description(model, ident, guid, dt, init, stop, about, units or {})
        out.parent.mkdir(parents=True, exist_ok=True)
        part = out.with_name(out.name + ".part")
        with zipfile.ZipFile(part, "w", compression=zipfile.ZIP_DEFLATED) as zf:
            zf.writestr("modelDescription.xml", xml)
            zf.write(lib, f"binaries/linux64/{ident}.so")
            zf.writestr(f"sources/{ident}.c", source)
            zf.writestr("resources/enginebench.json", json.dumps(resources, indent=1))
        part.replace(out)
    return out


def simulate_fmu(path: str | Path, U: np.ndarray, y_meas: np.ndarray, init: int, dt: float, timing: bool = False
                 ) -> tuple[np.ndarray, np.ndarray | None]:
    """Drive the FMU with fmpy as a co-simulation master: per step set the inputs (and the measured outputs),
    read the outputs, ``doStep(t, dt)``. Returns the outputs (n, targets) and, with ``timing``, each step's
    seconds as seen through fmpy (set, get and doStep, Python calls included)."""
    try:
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import FMU2Slave
    except ImportError:
        raise MethodError("checking an FMU needs fmpy: pip install \"enginebench[fmu]\"") from None
    import shutil
    from time import perf_counter

    md = read_model_description(str(path))
    unzipped = extract(str(path))
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipped, modelIdentifier=md.coSimulation.modelIdentifier,
                    instanceName="enginebench-check")
    try:
        variables = {v.name: v for v in md.modelVariables}
        ins = [v.valueReference for v in md.modelVariables if v.causality == "input" and v.type == "Real"]
        outs = [v.valueReference for v in md.modelVariables if v.causality == "output" and v.type == "Real"]
        fmu.instantiate()
        fmu.setupExperiment(startTime=0.0)
        fmu.setInteger([variables["init_samples"].valueReference], [max(int(init), 1)])
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        n, ny = len(U), len(outs)
        Ym = np.zeros((n, ny))
        w = np.asarray(y_meas, dtype=np.float64).reshape(-1, ny)[:n]
        Ym[:len(w)] = w
        values = np.hstack([np.asarray(U, dtype=np.float64).reshape(n, -1), Ym])
        Y = np.empty((n, ny))
        times = np.empty(n) if timing else None
        for i in range(n):
            t0 = perf_counter()
            fmu.setReal(ins, values[i].tolist())
            Y[i] = fmu.getReal(outs)
            fmu.doStep(currentCommunicationPoint=i * dt, communicationStepSize=dt)
            if times is not None:
                times[i] = perf_counter() - t0
        fmu.terminate()
    finally:
        fmu.freeInstance()
        shutil.rmtree(unzipped, ignore_errors=True)
    return Y, times
