// wandcal_trigger: reference firmware for the strobe trigger, protocol wandcal-trigger/1
// (docs/trigger-protocol.md). Pulses the cameras' trigger inputs and the IR strobes together and
// reports every pulse with its counter and its time in microseconds.
//
// Board: any Arduino with native USB (Leonardo, Micro, Zero, Due, RP2040, Teensy) or an UNO/Nano
// through its USB-serial bridge at 115200 baud. Wire TRIGGER_PINS to the cameras' opto-isolated
// trigger inputs (through the driver stage your cameras need) and STROBE_PIN to the LED ring
// driver's enable input. The host side is drivers/trigger.py; the emulator
// (wandcal trigger-emulator) implements the same protocol and is what the tests run against.
//
// Timing: pulses are scheduled on micros() in loop(). The schedule is absolute (pulse k of a run
// is due at start + k * period), so jitter does not accumulate; loop() latency adds a few
// microseconds of jitter per pulse, far below a camera's exposure. The reported t_us is the
// micros() reading when the lines went high.

#include <Arduino.h>

static const char *PROTOCOL = "wandcal-trigger/1";
static const char *FIRMWARE = "arduino-ref";
static const char *VERSION = "1.0";

static const uint8_t TRIGGER_PINS[] = {2, 3, 4, 5, 6, 7, 8, 9};
static const uint8_t N_LINES = sizeof(TRIGGER_PINS);
static const uint8_t STROBE_PIN = 10;
static const uint32_t TRIGGER_WIDTH_US = 100;  // long enough for every opto-isolated input we know

static const float MIN_RATE_HZ = 0.1f;
static const float MAX_RATE_HZ = 2000.0f;
static const uint32_t MIN_STROBE_US = 10;
static const uint32_t MAX_STROBE_US = 100000;

static float rate_hz = 100.0f;
static uint32_t strobe_us = 500;
static uint32_t counter = 0;          // pulses since power-on
static bool running = false;
static bool limited = false;
static uint32_t remaining = 0;
static uint32_t run_start_us = 0;
static uint32_t run_index = 0;
static uint32_t period_us = 10000;
static bool lines_high = false;
static bool strobe_high = false;
static uint32_t high_since_us = 0;

static char buf[48];
static uint8_t len = 0;

static void setLines(uint8_t level) {
  for (uint8_t i = 0; i < N_LINES; i++) digitalWrite(TRIGGER_PINS[i], level);
}

static void reply(const char *a, const char *b = nullptr) {
  Serial.print(a);
  if (b) { Serial.print(' '); Serial.print(b); }
  Serial.print('\n');
}

static void handle(char *line) {
  char *verb = strtok(line, " \r");
  char *arg = strtok(nullptr, " \r");
  if (!verb) { reply("ERR UNKNOWN empty command; send HELLO, RATE, STROBE, START, STOP or STATUS"); return; }
  for (char *p = verb; *p; ++p) *p = toupper(*p);
  if (!strcmp(verb, "HELLO")) {
    Serial.print("HELLO "); Serial.print(PROTOCOL);
    Serial.print(" firmware="); Serial.print(FIRMWARE);
    Serial.print(" version="); Serial.print(VERSION);
    Serial.print(" lines="); Serial.print(N_LINES); Serial.print('\n');
  } else if (!strcmp(verb, "STATUS")) {
    Serial.print("STATUS running="); Serial.print(running ? 1 : 0);
    Serial.print(" rate="); Serial.print(rate_hz);
    Serial.print(" strobe="); Serial.print(strobe_us);
    Serial.print(" counter="); Serial.print(counter);
    Serial.print(" remaining="); Serial.print(remaining);
    Serial.print(" t_us="); Serial.print(micros()); Serial.print('\n');
  } else if (!strcmp(verb, "STOP")) {
    running = false;
    Serial.print("OK STOP "); Serial.print(counter); Serial.print('\n');
  } else if (running) {
    if (!strcmp(verb, "RATE") || !strcmp(verb, "STROBE") || !strcmp(verb, "START"))
      reply("ERR BUSY", "already running; send STOP first");
    else
      reply("ERR UNKNOWN", "not a command; send HELLO, RATE, STROBE, START, STOP or STATUS");
  } else if (!strcmp(verb, "RATE")) {
    float hz = arg ? atof(arg) : 0.0f;
    if (hz < MIN_RATE_HZ || hz > MAX_RATE_HZ) { reply("ERR BADARG", "RATE needs a frequency in Hz from 0.1 to 2000"); return; }
    rate_hz = hz;
    period_us = (uint32_t)(1e6f / hz + 0.5f);
    Serial.print("OK RATE "); Serial.print(rate_hz); Serial.print('\n');
  } else if (!strcmp(verb, "STROBE")) {
    long us = arg ? atol(arg) : -1;
    if (us < (long)MIN_STROBE_US || us > (long)MAX_STROBE_US || (uint32_t)us >= period_us) {
      reply("ERR BADARG", "STROBE needs a width in us from 10 to 100000, shorter than the pulse period");
      return;
    }
    strobe_us = (uint32_t)us;
    Serial.print("OK STROBE "); Serial.print(strobe_us); Serial.print('\n');
  } else if (!strcmp(verb, "START")) {
    long n = arg ? atol(arg) : 0;
    if (n < 0) { reply("ERR BADARG", "START takes a whole number of pulses (0: until STOP)"); return; }
    remaining = (uint32_t)n;
    limited = n > 0;
    running = true;
    run_index = 0;
    run_start_us = micros();
    Serial.print("OK START "); Serial.print(n); Serial.print('\n');
  } else {
    reply("ERR UNKNOWN", "not a command; send HELLO, RATE, STROBE, START, STOP or STATUS");
  }
}

void setup() {
  for (uint8_t i = 0; i < N_LINES; i++) pinMode(TRIGGER_PINS[i], OUTPUT);
  pinMode(STROBE_PIN, OUTPUT);
  setLines(LOW);
  digitalWrite(STROBE_PIN, LOW);
  Serial.begin(115200);
}

void loop() {
  uint32_t now = micros();
  // end the trigger pulse and the strobe (unsigned subtraction survives the micros() wrap)
  if (lines_high && now - high_since_us >= TRIGGER_WIDTH_US) { setLines(LOW); lines_high = false; }
  if (strobe_high && now - high_since_us >= strobe_us) { digitalWrite(STROBE_PIN, LOW); strobe_high = false; }

  if (running && !lines_high && !strobe_high && now - run_start_us >= run_index * period_us) {
    digitalWrite(STROBE_PIN, HIGH);
    setLines(HIGH);
    high_since_us = micros();
    lines_high = strobe_high = true;
    Serial.print("P "); Serial.print(counter); Serial.print(' '); Serial.print(high_since_us); Serial.print('\n');
    counter++;
    run_index++;
    if (limited && --remaining == 0) {
      running = false;
      Serial.print("DONE "); Serial.print(counter); Serial.print('\n');
    }
  }

  while (Serial.available()) {
    char c = (char)Serial.read();
    if (c == '\n') {
      buf[len] = '\0';
      handle(buf);
      len = 0;
    } else if (len < sizeof(buf) - 1) {
      buf[len++] = c;
    }
  }
}
