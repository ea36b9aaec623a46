//! The double-exponential and KSP closures as moment-path problems (`003_d2fc48a470e528fc.txt`
//! (II.54)–(II.65)): work in progress.
