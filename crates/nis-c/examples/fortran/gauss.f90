!> gauss.f90: a narrow 3-d Gaussian integrated by neural importance sampling from Fortran.
!>
!> The integrand keeps state in SAVE variables (calls, points, a re-entrancy flag): safe, since
!> by default the library calls it from one thread at a time, with whole batches.
!>
!>   cargo build --release -p nis-c
!>   mkdir -p target/fortran
!>   gfortran -J target/fortran crates/nis-c/examples/fortran/nis.f90 \
!>       crates/nis-c/examples/fortran/gauss.f90 target/release/libnis_c.a -lm -lpthread -ldl \
!>       -o target/fortran/gauss && target/fortran/gauss
!>
!> (-J puts the module files nis.mod and gauss_integrand.mod in target/fortran, not in the
!> working directory.)
module gauss_integrand
  use, intrinsic :: iso_c_binding
  implicit none
  real(c_double), parameter :: sigma = 0.1d0, pi = 3.14159265358979324d0
  integer, save :: calls = 0, overlaps = 0
  integer(c_int64_t), save :: points = 0
  logical, save :: busy = .false.
contains
  !> exp(-|x - ½|²/2σ²)/(2πσ²)^(d/2): ∫ over the cube = erf(1/(2√2 σ))^d.
  integer(c_int) function gauss(x, n, dim, out, user) bind(c)
    integer(c_size_t), value :: n, dim
    real(c_double), intent(in) :: x(dim, n)
    real(c_double), intent(out) :: out(n)
    type(c_ptr), value :: user
    integer(c_size_t) :: i
    if (busy) overlaps = overlaps + 1
    busy = .true.
    calls = calls + 1
    points = points + n
    do i = 1, n
       out(i) = exp(-sum((x(:, i) - 0.5d0)**2) / (2 * sigma**2)) &
            / (2 * pi * sigma**2)**(0.5d0 * dim)
    end do
    busy = .false.
    ! This integrand takes no user data: a pointer given anyway is a caller's mistake, reported
    ! as a non-zero status (the call then fails with NIS_ERR_CALLBACK).
    gauss = 0
    if (c_associated(user)) gauss = 1
  end function gauss

  !> A channel that maps each coordinate through u -> u**2 (density 1/(2 sqrt(x)) per axis):
  !> it leans away from the centre, so the multi-channel estimate must still come out right.
  integer(c_int) function square_sample(input, n, dim, out, user) bind(c)
    integer(c_size_t), value :: n, dim
    real(c_double), intent(in) :: input(dim, n)
    real(c_double), intent(out) :: out(dim, n)
    type(c_ptr), value :: user
    out = input**2
    square_sample = 0
    if (c_associated(user)) square_sample = 1
  end function square_sample

  integer(c_int) function square_density(input, n, dim, out, user) bind(c)
    integer(c_size_t), value :: n, dim
    real(c_double), intent(in) :: input(dim, n)
    real(c_double), intent(out) :: out(n)
    type(c_ptr), value :: user
    integer(c_size_t) :: i
    do i = 1, n
       out(i) = product(0.5d0 / sqrt(max(input(:, i), 1d-300)))
    end do
    square_density = 0
    if (c_associated(user)) square_density = 1
  end function square_density

  !> The identity map: density 1 in the cube, 0 outside. The channels take no user data (a
  !> pointer given anyway is reported as a non-zero status, as gauss does).
  integer(c_int) function flat_sample(input, n, dim, out, user) bind(c)
    integer(c_size_t), value :: n, dim
    real(c_double), intent(in) :: input(dim, n)
    real(c_double), intent(out) :: out(dim, n)
    type(c_ptr), value :: user
    out = input
    flat_sample = 0
    if (c_associated(user)) flat_sample = 1
  end function flat_sample

  integer(c_int) function flat_density(input, n, dim, out, user) bind(c)
    integer(c_size_t), value :: n, dim
    real(c_double), intent(in) :: input(dim, n)
    real(c_double), intent(out) :: out(n)
    type(c_ptr), value :: user
    integer(c_size_t) :: i
    do i = 1, n
       out(i) = merge(1d0, 0d0, all(input(:, i) >= 0 .and. input(:, i) <= 1))
    end do
    flat_density = 0
    if (c_associated(user)) flat_density = 1
  end function flat_density
end module gauss_integrand

program gauss_nis
  use, intrinsic :: iso_c_binding
  use nis
  use gauss_integrand
  implicit none
  type(c_ptr) :: integ, mc
  type(nis_result) :: r
  type(nis_channel) :: channels(2)
  real(c_double) :: weights(2), means(2), sdevs(2)
  integer(c_int64_t) :: counts(2)
  real(c_double) :: exact
  logical :: ok

  exact = erf(0.5d0 / (sqrt(2d0) * sigma))**3

  ! A config error comes back as a status and a message.
  if (nis_create('{"method": "nis", "dimension": 3}' // c_null_char, integ) /= NIS_ERR_CONFIG) &
       stop 'a bad config was accepted'
  print '(a, a)', 'expected error: ', nis_last_error()

  if (nis_create('{"method": "nis", "dim": 3, "seed": 3, "nis": {"batch": 1024}}' &
       // c_null_char, integ) /= NIS_OK) then
     print '(a, a)', 'create: ', nis_last_error()
     stop 1
  end if
  if (nis_integrate(integ, c_funloc(gauss), c_null_ptr, 200000_c_int64_t, r) /= NIS_OK) then
     print '(a, a)', 'integrate: ', nis_last_error()
     stop 1
  end if
  print '(a, f10.6, a, f10.6, a, f10.6, a, i0, a, i0)', 'gauss 3d: ', r%value, ' +- ', &
       r%std_err, ' (exact ', exact, '), calls ', calls, ', points ', points
  ok = abs(r%value - exact) < 5 * r%std_err .and. r%std_err < 0.01d0 &
       .and. points == r%n_eval .and. overlaps == 0

  ! To a precision instead of a budget: 0.1% relative error, at most 10**7 evaluations.
  if (nis_integrate_to(integ, c_funloc(gauss), c_null_ptr, 1d-3, 0d0, 10000000_c_int64_t, &
       0d0, r) /= NIS_OK) then
     print '(a, a)', 'integrate_to: ', nis_last_error()
     stop 1
  end if
  print '(a, f10.6, a, f10.6, a, i0)', 'gauss 3d to 1e-3: ', r%value, ' +- ', r%std_err, &
       ', evaluations ', r%n_eval
  ok = ok .and. nis_result_stop(integ) == NIS_STOP_TARGET .and. r%std_err <= 1d-3 * r%value &
       .and. abs(r%value - exact) < 5 * r%std_err
  call nis_free(integ)

  ! Through two channels (the identity and u -> u**2 per axis), VEGAS+ per channel.
  channels(1) = nis_channel(c_funloc(flat_sample), c_funloc(flat_density), c_null_ptr, 0d0, &
       c_null_funptr)
  channels(2) = nis_channel(c_funloc(square_sample), c_funloc(square_density), c_null_ptr, 0d0, &
       c_null_funptr)
  if (nis_multichannel_create('{"method": "vegas", "dim": 3, "seed": 3}' // c_null_char, &
       channels, 2_c_size_t, c_null_ptr, mc) /= NIS_OK) then
     print '(a, a)', 'multichannel_create: ', nis_last_error()
     stop 1
  end if
  if (nis_multichannel_integrate(mc, c_funloc(gauss), c_null_ptr, 400000_c_int64_t, r) &
       /= NIS_OK) then
     print '(a, a)', 'multichannel_integrate: ', nis_last_error()
     stop 1
  end if
  if (nis_multichannel_channels(mc, weights, means, sdevs, counts, 2_c_size_t) /= NIS_OK) stop 1
  print '(a, f10.6, a, f10.6, a, 2f8.4)', 'gauss 3d, 2 channels: ', r%value, ' +- ', &
       r%std_err, ', weights ', weights
  ok = ok .and. abs(r%value - exact) < 5 * r%std_err .and. abs(sum(means) - r%value) < 1d-9
  ! The same channels to 0.1 %.
  if (nis_multichannel_integrate_to(mc, c_funloc(gauss), c_null_ptr, 1d-3, 0d0, 0_c_int64_t, &
       0d0, r) /= NIS_OK) then
     print '(a, a)', 'multichannel_integrate_to: ', nis_last_error()
     stop 1
  end if
  print '(a, f10.6, a, f10.6)', 'gauss 3d, 2 channels, to 0.1%: ', r%value, ' +- ', r%std_err
  ok = ok .and. nis_multichannel_stop(mc) == NIS_STOP_TARGET .and. &
       r%std_err <= 1d-3 * abs(r%value) .and. abs(r%value - exact) < 5 * r%std_err
  call nis_multichannel_free(mc)
  if (ok) then
     print '(a)', 'fortran: ok'
  else
     print '(a)', 'fortran: FAILED'
     stop 1
  end if
end program gauss_nis
