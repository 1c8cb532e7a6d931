// Load cell streamer for the dVRK cooperative-manipulation rig.
//
// Arduino Uno / Nano (ATmega328P, 16 MHz). Streams ADC samples of the load cell between
// the tool tips at 500 Hz and answers commands, exactly as specified in
// drivers/LOADCELL_PROTOCOL.md (protocol version 1). The host driver is
// drivers/loadcell/serial_driver.py (serial) or drivers/loadcell/can.py (CAN); the Python fake
// FakeLoadCellFirmware in drivers/loadcell/firmware_fake.py emulates this sketch.
//
// Build options (edit the #defines below):
//   LOADCELL_ADC = ADC_INA    instrumentation amplifier (e.g. INA125/INA826, gain set for
//                             0.1 V/N around a 2.5 V reference) into A0, 16 readings summed
//                             per sample; up to 1000 Hz. This is the rig's build.
//   LOADCELL_ADC = ADC_HX711  HX711 24-bit bridge ADC on DOUT=D3, SCK=D2, channel A gain
//                             128, RATE pin tied high (80 samples/s, the chip's maximum),
//                             so SET_RATE above 80 Hz is refused.
//   LOADCELL_TRANSPORT_CAN    define it to use an MCP2515 CAN module (CS = D10, library
//                             "mcp_can" by Cory Fowler) instead of USB serial.

#include <Arduino.h>

#define ADC_HX711 0
#define ADC_INA 1

#ifndef LOADCELL_ADC
#define LOADCELL_ADC ADC_INA
#endif
// #define LOADCELL_TRANSPORT_CAN

// Serial baud: the host takes it from here (drivers/loadcell/protocol.py BAUDRATE, rig.toml's
// [loadcell] baudrate default); a test fails when they differ. Exact on a 16 MHz AVR.
#define LOADCELL_BAUD 250000

#ifdef LOADCELL_TRANSPORT_CAN
#include <SPI.h>
#include <mcp_can.h>
#define CAN_BASE_ID 0x300   // samples B+0, commands B+1, replies B+2
#define CAN_CS_PIN 10
#define CAN_CRYSTAL MCP_8MHZ  // most blue MCP2515 boards carry 8 MHz; MCP_16MHZ otherwise
MCP_CAN can0(CAN_CS_PIN);
#endif

// ---------------------------------------------------------------- protocol constants
static const uint8_t PROTOCOL_VERSION = 1;
static const uint8_t FW_MAJOR = 1, FW_MINOR = 0, FW_PATCH = 0;
static const uint8_t SYNC0 = 0xA5, SYNC1 = 0x5A;
static const uint8_t MAX_PAYLOAD = 16;
static const uint8_t FRAME_OVERHEAD = 6;  // sync 2, LEN 1, TYPE 1, CRC 2

static const uint8_t T_SAMPLE = 0x01;
static const uint8_t CMD_IDENTIFY = 0x10, CMD_TARE = 0x11, CMD_SET_RATE = 0x12;
static const uint8_t CMD_START = 0x13, CMD_STOP = 0x14, CMD_STATUS = 0x15;
static const uint8_t REPLY = 0x80, T_ERROR = 0xFF;

static const uint8_t ERR_UNKNOWN_COMMAND = 0x01, ERR_BAD_CRC = 0x02, ERR_BAD_ARGUMENT = 0x03;
static const uint8_t ERR_BAD_LENGTH = 0x04, ERR_BUSY = 0x05, ERR_INCOMPLETE = 0x06;

static const uint8_t SAMPLE_SATURATED = 0x01;
static const uint8_t STATUS_STREAMING = 0x01, STATUS_TARE_BUSY = 0x02, STATUS_SATURATED = 0x04;

#if LOADCELL_ADC == ADC_HX711
static const uint16_t MAX_RATE_HZ = 80;
static const uint16_t DEFAULT_RATE_HZ = 80;
static const uint8_t HX711_DOUT = 3, HX711_SCK = 2;
#else
static const uint16_t MAX_RATE_HZ = 1000;
static const uint16_t DEFAULT_RATE_HZ = 500;
static const uint8_t INA_PIN = A0;
static const uint8_t INA_OVERSAMPLE = 16;
#endif

static const uint32_t RX_TIMEOUT_US = 50000UL;  // a command stopped this long is incomplete

// ---------------------------------------------------------------- state
static uint16_t rate_hz = DEFAULT_RATE_HZ;
static uint32_t period_us = 1000000UL / DEFAULT_RATE_HZ;
static uint32_t next_tick_us;
static bool streaming = false;
static uint32_t seq = 0;
static uint16_t rx_errors = 0;
static uint16_t tx_dropped = 0;
static bool last_saturated = false;

static uint8_t tare_left = 0;  // conversions still to average; 0 = no tare running
static uint8_t tare_n = 0;
static int64_t tare_sum = 0;

#if LOADCELL_ADC == ADC_HX711
static int32_t hx_latest = 0;
static bool hx_latest_saturated = false;
#endif

// ---------------------------------------------------------------- CRC-16/CCITT-FALSE
// poly 0x1021, init 0xFFFF, not reflected, xorout 0; check("123456789") = 0x29B1
static uint16_t crc16_update(uint16_t crc, uint8_t b) {
  crc ^= (uint16_t)b << 8;
  for (uint8_t i = 0; i < 8; i++) {
    crc = (crc & 0x8000) ? (uint16_t)((crc << 1) ^ 0x1021) : (uint16_t)(crc << 1);
  }
  return crc;
}

static uint16_t crc16(const uint8_t *data, uint8_t n) {
  uint16_t crc = 0xFFFF;
  for (uint8_t i = 0; i < n; i++) crc = crc16_update(crc, data[i]);
  return crc;
}

// little-endian field writers (the AVR is little-endian too, but be explicit)
static void put_u16(uint8_t *p, uint16_t v) { p[0] = v & 0xFF; p[1] = v >> 8; }
static void put_u32(uint8_t *p, uint32_t v) {
  p[0] = v & 0xFF; p[1] = (v >> 8) & 0xFF; p[2] = (v >> 16) & 0xFF; p[3] = (v >> 24) & 0xFF;
}

// ---------------------------------------------------------------- transport: send
#ifndef LOADCELL_TRANSPORT_CAN

// Builds a frame in `out` and returns its length.
static uint8_t build_frame(uint8_t *out, uint8_t type, const uint8_t *payload, uint8_t len) {
  out[0] = SYNC0; out[1] = SYNC1; out[2] = len; out[3] = type;
  for (uint8_t i = 0; i < len; i++) out[4 + i] = payload[i];
  uint16_t crc = crc16(out + 2, len + 2);
  out[4 + len] = crc & 0xFF;
  out[5 + len] = crc >> 8;
  return len + FRAME_OVERHEAD;
}

static void send_reply(uint8_t type, const uint8_t *payload, uint8_t len) {
  uint8_t frame[MAX_PAYLOAD + FRAME_OVERHEAD];
  uint8_t n = build_frame(frame, type, payload, len);
  Serial.write(frame, n);  // replies are rare and short: waiting for buffer room is fine
}

static void send_sample(uint32_t s, uint32_t t_us, int32_t counts, uint8_t flags) {
  uint8_t payload[13];
  put_u32(payload, s);
  put_u32(payload + 4, t_us);
  put_u32(payload + 8, (uint32_t)counts);
  payload[12] = flags;
  uint8_t frame[13 + FRAME_OVERHEAD];
  uint8_t n = build_frame(frame, T_SAMPLE, payload, 13);
  // Never block the sample clock: if the USB host is not reading, drop the frame. Its
  // sequence number is used anyway, so the host counts the loss as a gap.
  if (Serial.availableForWrite() >= n) {
    Serial.write(frame, n);
  } else if (tx_dropped < 0xFFFF) {
    tx_dropped++;
  }
}

#else  // CAN

static void send_reply(uint8_t type, const uint8_t *payload, uint8_t len) {
  uint8_t data[8];
  data[0] = type;
  for (uint8_t i = 0; i < len && i < 7; i++) data[1 + i] = payload[i];
  can0.sendMsgBuf(CAN_BASE_ID + 2, 0, len + 1, data);
}

static void send_sample(uint32_t s, uint32_t t_us, int32_t counts, uint8_t flags) {
  if (counts > 8388607L) { counts = 8388607L; flags |= SAMPLE_SATURATED; }
  if (counts < -8388608L) { counts = -8388608L; flags |= SAMPLE_SATURATED; }
  uint8_t data[8];
  data[0] = (s & 0x7F) | ((flags & SAMPLE_SATURATED) ? 0x80 : 0x00);
  data[1] = counts & 0xFF;
  data[2] = (counts >> 8) & 0xFF;
  data[3] = (counts >> 16) & 0xFF;
  put_u32(data + 4, t_us);
  if (can0.sendMsgBuf(CAN_BASE_ID + 0, 0, 8, data) != CAN_OK && tx_dropped < 0xFFFF) tx_dropped++;
}

#endif

static void send_error(uint8_t offending_type, uint8_t code) {
  uint8_t p[2] = {offending_type, code};
  send_reply(T_ERROR, p, 2);
}

// ---------------------------------------------------------------- ADC
#if LOADCELL_ADC == ADC_HX711

static bool hx711_ready() { return digitalRead(HX711_DOUT) == LOW; }

// 24 data bits MSB first, then one more pulse to select channel A, gain 128 for the next
// conversion. Interrupts are off so SCK never stays high for 60 us (that powers it down).
static int32_t hx711_read() {
  uint32_t v = 0;
  noInterrupts();
  for (uint8_t i = 0; i < 24; i++) {
    digitalWrite(HX711_SCK, HIGH);
    delayMicroseconds(1);
    v = (v << 1) | (digitalRead(HX711_DOUT) == HIGH ? 1 : 0);
    digitalWrite(HX711_SCK, LOW);
    delayMicroseconds(1);
  }
  digitalWrite(HX711_SCK, HIGH);
  delayMicroseconds(1);
  digitalWrite(HX711_SCK, LOW);
  interrupts();
  if (v & 0x800000UL) v |= 0xFF000000UL;  // sign-extend 24 -> 32 bits
  return (int32_t)v;
}

// Called from loop(): keeps the newest conversion so a tick never waits for the chip.
static void hx711_poll() {
  if (hx711_ready()) {
    hx_latest = hx711_read();
    hx_latest_saturated = (hx_latest == 8388607L || hx_latest == -8388608L);
  }
}

static int32_t convert(bool *saturated) {
  *saturated = hx_latest_saturated;
  return hx_latest;
}

#else

static int32_t convert(bool *saturated) {
  uint16_t sum = 0;
  bool sat = false;
  for (uint8_t i = 0; i < INA_OVERSAMPLE; i++) {
    uint16_t r = analogRead(INA_PIN);
    if (r == 0 || r == 1023) sat = true;
    sum += r;
  }
  *saturated = sat;
  return (int32_t)sum - (int32_t)INA_OVERSAMPLE * 512;  // signed around mid-supply
}

#endif

// ---------------------------------------------------------------- commands
static void handle_command(uint8_t type, const uint8_t *p, uint8_t len) {
  uint8_t expected;
  switch (type) {
    case CMD_IDENTIFY: case CMD_START: case CMD_STOP: case CMD_STATUS: expected = 0; break;
    case CMD_TARE: expected = 1; break;
    case CMD_SET_RATE: expected = 2; break;
    default:
      rx_errors++;
      send_error(type, ERR_UNKNOWN_COMMAND);
      return;
  }
  if (len != expected) {
    rx_errors++;
    send_error(type, ERR_BAD_LENGTH);
    return;
  }
  uint8_t r[7] = {0};
  switch (type) {
    case CMD_IDENTIFY:
      r[0] = PROTOCOL_VERSION; r[1] = FW_MAJOR; r[2] = FW_MINOR; r[3] = FW_PATCH;
      r[4] = LOADCELL_ADC;
      put_u16(r + 5, MAX_RATE_HZ);
      send_reply(type | REPLY, r, 7);
      break;
    case CMD_STATUS:
      put_u16(r, rate_hz);
      r[2] = (streaming ? STATUS_STREAMING : 0) | (tare_left ? STATUS_TARE_BUSY : 0) |
             (last_saturated ? STATUS_SATURATED : 0);
      put_u16(r + 3, rx_errors);
      put_u16(r + 5, tx_dropped);
      send_reply(type | REPLY, r, 7);
      break;
    case CMD_SET_RATE: {
      uint16_t hz = (uint16_t)p[0] | ((uint16_t)p[1] << 8);
      if (hz < 1 || hz > MAX_RATE_HZ) {
        send_error(type, ERR_BAD_ARGUMENT);
        break;
      }
      rate_hz = hz;
      period_us = 1000000UL / hz;
      next_tick_us = micros() + period_us;
      put_u16(r, hz);
      send_reply(type | REPLY, r, 2);
      break;
    }
    case CMD_START:
      streaming = true;
      send_reply(type | REPLY, r, 0);
      break;
    case CMD_STOP:
      streaming = false;
      send_reply(type | REPLY, r, 0);
      break;
    case CMD_TARE:
      if (p[0] == 0) {
        send_error(type, ERR_BAD_ARGUMENT);
      } else if (tare_left) {
        send_error(type, ERR_BUSY);
      } else {
        tare_left = tare_n = p[0];
        tare_sum = 0;  // the reply is sent by tick() after the last conversion
      }
      break;
  }
}

// ---------------------------------------------------------------- serial receive parser
#ifndef LOADCELL_TRANSPORT_CAN
// A small byte buffer parsed like the host's FrameParser: find sync, check LEN, wait for
// the whole frame, check the CRC; when the CRC fails but a frame header starts inside,
// the command was cut short (reply "incomplete") and parsing resumes at that header.
static uint8_t rx_buf[48];
static uint8_t rx_n = 0;
static uint32_t rx_last_us = 0;

static void rx_drop(uint8_t n) {
  if (n > rx_n) n = rx_n;
  memmove(rx_buf, rx_buf + n, rx_n - n);
  rx_n -= n;
}

static bool known_type(uint8_t t) {
  return t == T_SAMPLE || t == T_ERROR || (t >= CMD_IDENTIFY && t <= CMD_STATUS) ||
         (t >= (CMD_IDENTIFY | REPLY) && t <= (CMD_STATUS | REPLY));
}

static void rx_parse() {
  for (;;) {
    // find the sync pair
    uint8_t i = 0;
    while (i + 1 < rx_n && !(rx_buf[i] == SYNC0 && rx_buf[i + 1] == SYNC1)) i++;
    if (i + 1 >= rx_n) {  // none: keep a trailing A5, it may be half a sync
      uint8_t keep = (rx_n && rx_buf[rx_n - 1] == SYNC0) ? 1 : 0;
      rx_drop(rx_n - keep);
      return;
    }
    rx_drop(i);
    if (rx_n < 4) return;
    uint8_t len = rx_buf[2], type = rx_buf[3];
    if (len > MAX_PAYLOAD) {
      rx_errors++;
      send_error(type, ERR_BAD_LENGTH);
      rx_drop(2);
      continue;
    }
    uint8_t end = len + FRAME_OVERHEAD;
    if (rx_n < end) return;
    uint16_t got = (uint16_t)rx_buf[end - 2] | ((uint16_t)rx_buf[end - 1] << 8);
    if (crc16(rx_buf + 2, len + 2) == got) {
      handle_command(type, rx_buf + 4, len);
      rx_drop(end);
      continue;
    }
    uint8_t j = 1;
    bool need_more = false;
    for (; j + 1 < end; j++) {
      if (rx_buf[j] != SYNC0 || rx_buf[j + 1] != SYNC1) continue;
      if (rx_n < j + 4) { need_more = true; break; }
      if (rx_buf[j + 2] <= MAX_PAYLOAD && known_type(rx_buf[j + 3])) break;
    }
    if (need_more) return;
    rx_errors++;
    if (j + 1 < end) {
      send_error(type, ERR_INCOMPLETE);
      rx_drop(j);
    } else {
      send_error(type, ERR_BAD_CRC);
      rx_drop(end);
    }
  }
}

static void serial_receive() {
  while (Serial.available() > 0) {
    if (rx_n >= sizeof(rx_buf)) rx_drop(1);  // cannot happen with LEN <= 16; stay safe
    rx_buf[rx_n++] = (uint8_t)Serial.read();
    rx_last_us = micros();
    rx_parse();
  }
  if (rx_n > 0 && (uint32_t)(micros() - rx_last_us) > RX_TIMEOUT_US) {
    if (rx_n >= 3 && rx_buf[0] == SYNC0 && rx_buf[1] == SYNC1) {
      rx_errors++;
      send_error(rx_n > 3 ? rx_buf[3] : 0, ERR_INCOMPLETE);
    }
    rx_n = 0;
  }
}
#else
static void can_receive() {
  if (can0.checkReceive() != CAN_MSGAVAIL) return;
  unsigned long id;
  uint8_t len;
  uint8_t data[8];
  if (can0.readMsgBuf(&id, &len, data) != CAN_OK) return;
  if (id != CAN_BASE_ID + 1) return;
  if (len == 0) {
    rx_errors++;
    send_error(0, ERR_BAD_LENGTH);
    return;
  }
  handle_command(data[0], data + 1, len - 1);
}
#endif

// ---------------------------------------------------------------- sampling
static void tick() {
  uint32_t t_us = micros();
  bool sat;
  int32_t counts = convert(&sat);
  last_saturated = sat;
  if (tare_left) {
    tare_sum += counts;
    if (--tare_left == 0) {
      // mean rounded half away from zero
      int64_t mag = tare_sum < 0 ? -tare_sum : tare_sum;
      int32_t mean = (int32_t)((mag + tare_n / 2) / tare_n);
      if (tare_sum < 0) mean = -mean;
      uint8_t r[5];
      put_u32(r, (uint32_t)mean);
      r[4] = tare_n;
      send_reply(CMD_TARE | REPLY, r, 5);
    }
  }
  if (streaming) {
    send_sample(seq, t_us, counts, sat ? SAMPLE_SATURATED : 0);
    seq++;
  }
}

void setup() {
#if LOADCELL_ADC == ADC_HX711
  pinMode(HX711_DOUT, INPUT);
  pinMode(HX711_SCK, OUTPUT);
  digitalWrite(HX711_SCK, LOW);  // SCK low wakes the chip; first conversion after ~400 ms
#else
  // ADC clock 16 MHz / 32 = 500 kHz: 26 us per reading, 16 readings in ~0.42 ms, so a
  // 500 Hz tick (2 ms) has room for serial work. 10-bit accuracy holds to ~1 MHz.
  ADCSRA = (ADCSRA & ~0x07) | 0x05;
  analogReference(DEFAULT);
#endif
#ifdef LOADCELL_TRANSPORT_CAN
  while (can0.begin(MCP_ANY, CAN_500KBPS, CAN_CRYSTAL) != CAN_OK) delay(100);
  can0.setMode(MCP_NORMAL);
#else
  Serial.begin(LOADCELL_BAUD);
#endif
  next_tick_us = micros() + period_us;
}

void loop() {
#ifdef LOADCELL_TRANSPORT_CAN
  can_receive();
#else
  serial_receive();
#endif
#if LOADCELL_ADC == ADC_HX711
  hx711_poll();
#endif
  uint32_t now = micros();
  if ((int32_t)(now - next_tick_us) >= 0) {
    next_tick_us += period_us;
    // fell more than 100 ms behind (e.g. a long blocking write): restart the schedule
    // instead of bursting samples
    if ((int32_t)(now - next_tick_us) > 100000L) next_tick_us = now + period_us;
    tick();
  }
}
